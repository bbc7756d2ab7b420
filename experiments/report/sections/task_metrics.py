"""The task-metric tables (the supplement's Table 4 protocol): a task's own per-episode metrics per policy, the
rate's Wilson interval over every episode, and a plain reading for a task judged by a rate."""

from __future__ import annotations

from ape_jax import tasks
from experiments.report import stats
from experiments.report.analysis import (LEARNED, Group, bootstrap_mean, group_title, is_rate, ordered, per_seed,
                                         rate_reading, task_metric_rows, verdict)
from experiments.report.sections.common import Context, Section, ci_text


# How the task-metrics table heads a task's own metrics, and the factor it shows them at (rates in %); a metric
# not listed is headed by its name, and a task's main metric (a rate) is shown in %.
NAMES = {"bc-so": "BC-SO", "bc-oh": "BC-OH", "ours-step": "Ours"}   # how the reading names the methods it compares
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
            v = per_seed(runs, key, scale)
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


def task_reading(m: Group) -> list[str]:
    """Plain sentences under a rate-judged task's table (ToyCar), from `analysis.rate_reading`: whether BC-SO
    learned the task, Ours − BC-OH and BC-OH − BC-SO on the main rate with their bootstrap intervals and
    verdicts, and whether BC-OH's inertia (`stuck`: standing still while free to go) appears; empty for a task
    judged by a return."""
    r = rate_reading(m)
    if r is None:
        return []
    out = []
    if r.bcso is not None:
        b = r.bcso
        out.append(f"BC-SO {r.metric}: {b.mean:.1f}% [{b.low:.1f}, {b.high:.1f}] over {b.seeds} seeds"
                   + (f" × {r.episodes:,} evaluation episodes" if r.episodes is not None else "")
                   + (" — a plain BC-SO policy has learned the task." if r.learned else
                      f" — at least {LEARNED:.0f}% on average." if b.mean >= LEARNED else f" — below {LEARNED:.0f}%: "
                      "the policies have not learned the task at this budget, and the comparisons below say little."))
    for a, b, ci in r.differences:
        out.append(f"{NAMES[a]} − {NAMES[b]}: {ci.diff:+.1f} points of {r.metric} ({ci_text(ci)}): "
                   f"{verdict(ci, NAMES[a], NAMES[b])}.")
    if r.inertia is not None:
        others = ", ".join(f"{NAMES[k]} {v:.1f}%" for k, v in r.others.items())
        i = r.inertia
        out.append(f"Inertia (standing still for {tasks.get(m.env).title}'s stuck time while free to go): BC-OH "
                   f"{i.mean:.1f}% of episodes [{i.low:.1f}, {i.high:.1f}]" + (f" ({others})" if others else "")
                   + (" — it appears." if i.mean > 0 else " — it does not appear in these episodes."))
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
