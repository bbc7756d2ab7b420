"""The task-metric tables (the supplement's Table 4 protocol): a task's own per-episode metrics per policy, the
rate's Wilson interval over every episode, and a plain reading for a task judged by a rate."""

from __future__ import annotations

import numpy as np

from ape_jax import tasks
from experiments.report import stats
from experiments.report.analysis import (Group, bootstrap_difference, bootstrap_mean, group_title, is_rate, ordered,
                                         task_metric_rows, verdict)
from experiments.report.sections.common import Context, Section, ci_text


# How the task-metrics table heads a task's own metrics, and the factor it shows them at (rates in %); a metric
# not listed is headed by its name, and a task's main metric (a rate) is shown in %.
METRIC_HEADINGS = {"red_light_violations": ("red-light violations", 1.0), "avg_speed": ("average speed", 1.0),
                   "stuck": ("stuck %", 100.0)}


def _metric_heading(m: Group, metric: str) -> tuple[str, float]:
    if metric in METRIC_HEADINGS:
        return METRIC_HEADINGS[metric]
    return (f"{metric} %", 100.0) if metric == m.metric and is_rate(m) else (metric.replace("_", " "), 1.0)


def task_table(m: Group) -> str | None:
    """A task's own per-episode metrics (its `metrics`; the supplement's Table 4 protocol): BC-SO, BC-OH and Ours
    (THR 10%, W 5), every metric as mean ± std over seeds (of each seed's episode mean) with the mean's 95%
    bootstrap interval over seeds, and beside them the paper's main metric where the task records it
    (`Task.paper`). None for a task without metrics."""
    metrics = m.task_metrics
    rows = task_metric_rows(m)
    if not metrics or not rows:
        return None
    paper = tasks.get(m.env).paper
    heads = [_metric_heading(m, k) for k in metrics]
    paper_head = [f"paper: {m.metric}" + (" %" if is_rate(m) else "")] if paper else []
    wilson_head = [f"{m.metric} % of all episodes [Wilson 95%]"] if is_rate(m) else []
    lines = ["| method | seeds | " + " | ".join([name for name, _ in heads] + wilson_head + paper_head) + " |",
             "|---|---:|" + "---:|" * (len(heads) + len(wilson_head) + len(paper_head))]
    for lab, method, runs in rows:
        cells = []
        for key, (_, scale) in zip(metrics, heads):
            v = _per_seed(runs, key, scale)
            if not len(v):
                cells.append("—")
                continue
            _, low, high = bootstrap_mean(v)
            cells.append(f"{v.mean():.2f} ± {v.std():.2f} [{low:.2f}, {high:.2f}]")
        if wilson_head:
            cells.append(wilson_cell(runs, m.metric))
        if paper:
            cells.append(f"{paper[method][0]} ± {paper[method][1]}" if method in paper else "—")
        lines.append(f"| {lab} | {len(runs)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def wilson_cell(runs: list[dict], metric: str) -> str:
    """A rate over every evaluation episode of `runs` pooled, with Wilson's binomial interval (episodes as
    independent trials: it says how precisely the episodes measure the rate, the bootstrap over seeds how much
    it varies between trained policies)."""
    counted = [(r["eval"][metric], int(r["eval"]["episodes"])) for r in runs
               if metric in r["eval"] and r["eval"].get("episodes")]
    if not counted:
        return "—"
    e = stats.wilson(sum(round(rate * n) for rate, n in counted), sum(n for _, n in counted))
    return f"{100 * e.value:.2f} [{100 * e.low:.2f}, {100 * e.high:.2f}]"


def _per_seed(runs: list[dict], key: str, scale: float = 1.0) -> np.ndarray:
    return np.array([r["eval"][key] for r in runs if key in r["eval"]], float) * scale


def task_reading(m: Group) -> list[str]:
    """Plain sentences under a rate-judged task's table (ToyCar): whether BC-SO learned the task, Ours − BC-OH
    and BC-OH − BC-SO on the main rate with their bootstrap intervals and verdicts, and whether BC-OH's inertia
    (`stuck`: standing still while free to go) appears; empty for a task judged by a return."""
    if not is_rate(m):
        return []
    rows = {method: runs for _, method, runs in task_metric_rows(m)}
    metric, out = m.metric, []
    episodes = sorted({int(r["eval"]["episodes"]) for runs in rows.values() for r in runs if "episodes" in r["eval"]})
    if "bc-so" in rows:
        mean, low, high = bootstrap_mean(_per_seed(rows["bc-so"], metric, 100.0))
        out.append(f"BC-SO {metric}: {mean:.1f}% [{low:.1f}, {high:.1f}] over {len(rows['bc-so'])} seeds"
                   + (f" × {episodes[0]:,} evaluation episodes" if len(episodes) == 1 else "")
                   + (" — a plain BC-SO policy has learned the task." if low >= 90.0 else
                      " — at least 90% on average." if mean >= 90.0 else " — below 90%: the policies have not "
                      "learned the task at this budget, and the comparisons below say little."))
    for a, b, name_a, name_b in (("bc-oh", "bc-so", "BC-OH", "BC-SO"), ("ours-step", "bc-oh", "Ours", "BC-OH")):
        if a in rows and b in rows:
            ci = bootstrap_difference(_per_seed(rows[a], metric, 100.0), _per_seed(rows[b], metric, 100.0))
            out.append(f"{name_a} − {name_b}: {ci.diff:+.1f} points of {metric} ({ci_text(ci)}): "
                       f"{verdict(ci, name_a, name_b)}.")
    stuck = {method: _per_seed(runs, "stuck", 100.0) for method, runs in rows.items()}
    if "bc-oh" in stuck and len(stuck["bc-oh"]):
        others = ", ".join(f"{lab} {stuck[k].mean():.1f}%" for lab, k in (("BC-SO", "bc-so"), ("Ours", "ours-step"))
                           if k in stuck and len(stuck[k]))
        oh = stuck["bc-oh"]
        _, low, high = bootstrap_mean(oh)
        out.append(f"Inertia (standing still for {tasks.get(m.env).title}'s stuck time while free to go): BC-OH "
                   f"{oh.mean():.1f}% of episodes [{low:.1f}, {high:.1f}]" + (f" ({others})" if others else "")
                   + (" — it appears." if oh.mean() > 0 else " — it does not appear in these episodes."))
    return out


def task_metric_sections(ctx: Context) -> list[Section]:
    """Per group whose task records metrics of its own (`task_table`), in report order: the table, the wall time of
    its runs, and the plain reading of a rate-judged task."""
    out = []
    for key, m in ordered(ctx.merged):
        table = task_table(m)
        if not table:
            continue
        task = tasks.get(key.env)
        title = group_title(key, m.protocol, m.shows_protocol, with_obs=key.obs != task.default_obs)
        paper = (f"; the paper's {m.metric} rates beside (its own {task.title}, not ours)" if task.paper
                 else "")
        walls = [f"{src.timing['total_s'] / 60:,.0f} min" for src in m.sources
                 if (src.timing or {}).get("total_s")]
        machine = next(((src.system or {}).get("machine") for src in m.sources if src.system), None)
        wall = (f" Wall time of the run{'s' if len(walls) > 1 else ''}: {', '.join(walls)}"
                + (f" ({machine})" if machine else "") + ", compile included." if walls else "")
        reading = task_reading(m)
        out.append(Section(
            f"{title} (the supplement's Table 4 protocol)",
            f"{task.title}'s own metrics per policy, mean ± std over seeds of each seed's mean over "
            f"evaluation episodes, and in brackets the mean's 95% bootstrap interval over seeds"
            + (f"; the {m.metric} rate of all episodes pooled with its binomial (Wilson) interval"
               if is_rate(m) else "") + f"{paper}." + wall,
            [table, *([" ".join(reading), ""] if reading else [])]))
    return out
