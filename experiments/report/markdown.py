"""The report's markdown: every table, each file's provenance, and `build` (the whole section and its figures).

The numbers come from `experiments.report.analysis`, the figures from
`experiments.report.figures`; this module formats, and draws nothing itself
(`build` asks the figure builders for the figures it links). Every sentence
that states a result (the copycat map's, the plain reading's, the paper's
choices') is built from those numbers, never typed.
"""

from __future__ import annotations

import math
import os
import pathlib
import shlex

import numpy as np

from ape_jax import methods as methods_lib
from ape_jax import tasks
from ape_jax.pipeline import results as results_lib
from experiments.report import figures, stats
from experiments.report.analysis import (APE_SCALES, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, BRAX, FCA, MAP_METHODS,
                                         alpha_rows, policy_diagnostics, recipe_groups, recipe_rows, BudgetRow, MapPoint, budget_differences,
                                         budget_rows, extended_map, paper_budget_groups, thousands,
                                         DiagnosticsRow, PolicyDiagnostics, Spread, diagnostics_rows,
                                         diagnostics_thresholds, recipe_diagnostics, training_points,
                                         CopycatMap, Difference, Interval, Key, ReportError, WeightShares, best_of, hparams_suffix,
                                         display_metric, ordered, paper_step_row, percent, method_rows, group_title, bootstrap_unit, bootstrap_rows,
                                         choices, copycat_groups, copycat_map, expert_ape, extra_methods, file_stem,
                                         gap, groups_of, headline, history_difference, in_fca_family, is_rate,
                                         known_methods, label, longer_runs, loss_rows, merge, ours_differences, protocol_words,
                                         protocols_of, sensitivity, task_metric_rows, verdict, versus_bcoh,
                                         weight_shares, bootstrap_mean, bootstrap_difference)
from experiments.report.paper import PAPER_SENSITIVITY_TAU, PAPER_SENSITIVITY_W, PAPER_STEP, PAPER_TABLE5

# How the task-metrics table heads a task's own metrics, and the factor it shows them at (rates in %); a metric
# not listed is headed by its name, and a task's main metric (a rate) is shown in %.
METRIC_HEADINGS = {"red_light_violations": ("red-light violations", 1.0), "avg_speed": ("average speed", 1.0),
                   "stuck": ("stuck %", 100.0)}


def _cell(row: dict | None) -> str:
    if row is None:
        return "—"
    norm = f" ({row['normalized_mean']:.0f}%)" if row.get("normalized_mean") is not None else ""
    return f"{row['return_mean']:,.0f} ± {row['return_std']:,.0f}{norm}"


def _norm_cell(row: dict | None) -> str:
    return "—" if row is None or row.get("normalized_mean") is None else f"{row['normalized_mean']:.1f}"


def _generic(lab: str) -> str:
    """A headline label without the configuration a "best" row names (`"Ours, best step (thr 0.2, w 3)"` →
    `"Ours, best step"`): the row's name in a table with one column per task."""
    return lab.split(" (")[0] if lab.startswith("Ours, best") else lab


def _selected(lab: str, row: dict | None) -> str:
    """What a "best" row's cell adds on its own line: the configuration selected in that task; "" otherwise."""
    return f" <br>{hparams_suffix(row)[1:]}" if lab.startswith("Ours, best") and row is not None else ""


def state_table(merged: dict, obs: str = "pos", protocol: str = BRAX) -> str:
    """Every method per MuJoCo task with observations `obs` ("pos": MuJoCo-State, "image": MuJoCo-Image) under
    `protocol`: return mean ± std over seeds (% of expert), the methods besides ours those groups ran, our
    expert and a random policy."""
    groups = groups_of(merged, obs, protocol)
    if not groups:
        return ""
    extras = extra_methods({Key(m["env"], obs, protocol): m for m in groups})
    known = known_methods(merged)
    heads = [headline(m, extras, known) for m in groups]
    lines = ["| method | " + " | ".join(tasks.get(m["env"]).title for m in groups) + " |",
             "|---|" + "---:|" * len(groups)]
    for i, (lab, _) in enumerate(heads[0]):
        cells = []
        for head in heads:
            lab, row = head[i]
            cells.append(_cell(row) + _selected(lab, row))
        lines.append(f"| {_generic(lab)} | " + " | ".join(cells) + " |")
    experts = [m["expert"] for m in groups]
    lines.append("| expert (ours) | " + " | ".join("—" if x["return_mean"] is None else
                                                   f"{x['return_mean']:,.0f} ± {x['return_std'] or 0:,.0f}"
                                                   for x in experts) + " |")
    lines.append("| random policy | " + " | ".join("—" if x["random_return_mean"] is None else
                                                   f"{x['random_return_mean']:,.0f}" for x in experts) + " |")
    return "\n".join(lines) + "\n"


def versus_table(merged: dict, obs: str = "pos", protocol: str = BRAX) -> str:
    """The state table's rows against BC-OH, per task: each method's mean − BC-OH's over seeds (in `bootstrap_unit`), its
    95% bootstrap CI, bold where the interval excludes 0 with ≥ 2 seeds per arm; "" if no group has BC-OH."""
    groups = groups_of(merged, obs, protocol)
    extras = extra_methods({Key(m["env"], obs, protocol): m for m in groups})
    known = known_methods(merged)
    columns = [versus_bcoh(m, extras, known) for m in groups]
    if not any(ci is not None for col in columns for _, _, ci in col):
        return ""
    lines = ["| method − BC-OH | " + " | ".join(tasks.get(m["env"]).title for m in groups) + " |",
             "|---|" + "---:|" * len(groups)]
    for i, (lab, _, _) in enumerate(columns[0]):
        cells = []
        for col in columns:
            _, row, ci = col[i]
            if ci is None:
                cells.append("—")
                continue
            text = f"{ci.diff:+,.0f} [{ci.low:+,.0f}, {ci.high:+,.0f}]"
            bold = min(ci.n_a, ci.n_b) >= 2 and (ci.low > 0 or ci.high < 0)
            cells.append((f"**{text}**" if bold else text) + _selected(lab, row))
        lines.append(f"| {_generic(lab)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def versus_section(merged: dict, protocol: str) -> list[str]:
    """`versus_table` of the MuJoCo-State groups under `protocol` with its caption, or nothing."""
    table = versus_table(merged, "pos", protocol)
    if not table:
        return []
    return ["The same rows against BC-OH: each one's mean return − BC-OH's, over seeds, with a 95% percentile "
            f"bootstrap interval (each arm's seeds resampled independently, {BOOTSTRAP_RESAMPLES:,} times; numpy "
            f"seed {BOOTSTRAP_SEED}); **bold** where the interval excludes 0 (≥ 2 seeds per arm). Each arm keeps "
            "its own seeds (each task's \"every configuration\" table below gives them); the \"best\" rows were "
            "selected after the fact, so theirs are optimistic.", "", table]


def _agreed(values) -> object | None:
    """The one value all of `values` share (None if they differ, or any is None)."""
    values = list(values)
    return values[0] if values and values[0] is not None and all(v == values[0] for v in values) else None


def _horizon(p: dict) -> float | None:
    """Simulated time per episode in the environment's standard control steps (at its own frame skip), or None."""
    need = ("episode_length", "frame_skip", "standard_frame_skip")
    if any(not isinstance(p.get(k), (int, float)) or not p.get(k) for k in need):
        return None
    return p["episode_length"] * p["frame_skip"] / p["standard_frame_skip"]


def protocol_heading(groups: list[dict]) -> str:
    """The settings the groups' protocol dicts agree on, for a heading: `"frame skip 1, 500 standard steps of
    simulated time, 20,000 training transitions"`; "" if none is recorded."""
    ps = [m["protocol"] for m in groups]
    parts = []
    if (skip := _agreed(p.get("frame_skip") for p in ps)) is not None:
        parts.append(f"frame skip {skip}")
    if (h := _agreed(_horizon(p) for p in ps)) is not None:
        parts.append(f"{h:,.0f} standard steps of simulated time")
    if (n := _agreed(p.get("train_transitions") for p in ps)) is not None:
        parts.append(f"{n:,} training transitions")
    if not any(p.get("variant_of") for p in ps) and any(p.get("train_transitions") for p in ps):
        # files before the recipe records: whole episodes apart, the project's first recipe (`mlp`)
        parts.append("split by whole episodes, recipe mlp")
    return ", ".join(parts)


def protocol_details(groups: list[dict]) -> str:
    """One sentence with every setting the groups' protocols record, per task where they differ ("" if none)."""
    ps = {tasks.get(m["env"]).title: m["protocol"] for m in groups}

    def each(fmt, key):
        values = {t: p.get(key) for t, p in ps.items()}
        if all(v is None for v in values.values()):
            return None
        if (v := _agreed(values.values())) is not None:
            return fmt(v)
        return ", ".join(f"{t} {fmt(v)}" for t, v in values.items() if v is not None)

    parts = [("the environments' own frame skip", each(str, "standard_frame_skip")),
             ("frame skip", each(str, "frame_skip")),
             ("control steps per episode", each(lambda v: f"{v:,}", "episode_length")),
             ("rewards scaled by", each(lambda v: f"{v:g}", "reward_scale")),
             ("expert steps collected", each(lambda v: f"{v:,}", "collect_transitions")),
             ("training transitions", each(lambda v: f"{v:,}", "train_transitions")),
             ("validation transitions", each(lambda v: f"{v:,}", "val_transitions")),
             ("history", each(str, "history"))]
    parts = [f"{name} {value}" for name, value in parts if value is not None]
    return ("Recorded settings: " + "; ".join(parts) + ".") if parts else ""


def _metric_heading(m: dict, metric: str) -> tuple[str, float]:
    if metric in METRIC_HEADINGS:
        return METRIC_HEADINGS[metric]
    return (f"{metric} %", 100.0) if metric == m["metric"] and is_rate(m) else (metric.replace("_", " "), 1.0)


def task_table(m: dict) -> str | None:
    """A task's own per-episode metrics (its `metrics`; the supplement's Table 4 protocol): BC-SO, BC-OH and Ours
    (THR 10%, W 5), every metric as mean ± std over seeds (of each seed's episode mean) with the mean's 95%
    bootstrap interval over seeds, and beside them the paper's main metric where the task records it
    (`Task.paper`). None for a task without metrics."""
    metrics = m["task_metrics"]
    rows = task_metric_rows(m)
    if not metrics or not rows:
        return None
    paper = tasks.get(m["env"]).paper
    heads = [_metric_heading(m, k) for k in metrics]
    paper_head = [f"paper: {m['metric']}" + (" %" if is_rate(m) else "")] if paper else []
    wilson_head = [f"{m['metric']} % of all episodes [Wilson 95%]"] if is_rate(m) else []
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
            cells.append(_wilson_cell(runs, m["metric"]))
        if paper:
            cells.append(f"{paper[method][0]} ± {paper[method][1]}" if method in paper else "—")
        lines.append(f"| {lab} | {len(runs)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _wilson_cell(runs: list[dict], metric: str) -> str:
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


def task_reading(m: dict) -> list[str]:
    """Plain sentences under a rate-judged task's table (ToyCar): whether BC-SO learned the task, Ours − BC-OH
    and BC-OH − BC-SO on the main rate with their bootstrap intervals and verdicts, and whether BC-OH's inertia
    (`stuck`: standing still while free to go) appears; empty for a task judged by a return."""
    if not is_rate(m):
        return []
    rows = {method: runs for _, method, runs in task_metric_rows(m)}
    metric, out = m["metric"], []
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
            out.append(f"{name_a} − {name_b}: {ci.diff:+.1f} points of {metric} ({_ci(ci)}): "
                       f"{verdict(ci, name_a, name_b)}.")
    stuck = {method: _per_seed(runs, "stuck", 100.0) for method, runs in rows.items()}
    if "bc-oh" in stuck and len(stuck["bc-oh"]):
        others = ", ".join(f"{lab} {stuck[k].mean():.1f}%" for lab, k in (("BC-SO", "bc-so"), ("Ours", "ours-step"))
                           if k in stuck and len(stuck[k]))
        oh = stuck["bc-oh"]
        _, low, high = bootstrap_mean(oh)
        out.append(f"Inertia (standing still for {tasks.get(m['env']).title}'s stuck time while free to go): BC-OH "
                   f"{oh.mean():.1f}% of episodes [{low:.1f}, {high:.1f}]" + (f" ({others})" if others else "")
                   + (" — it appears." if oh.mean() > 0 else " — it does not appear in these episodes."))
    return out


def paper_table(merged: dict, protocol: str = BRAX) -> str:
    """Ours under `protocol` next to the supplement's Table 5 (BC-SO, BC-OH, FCA, Ours at step THR 10% W 5).

    Under the fca family our returns are on the paper's scale (rewards summed over the same simulated time, in
    standard control steps), so each cell is the absolute mean return, ours ± std over seeds, with the ratio
    to BC-OH of the same source in brackets as a secondary number, and a row for the experts (the paper does
    not publish its expert's return). Under other protocols the returns are on another scale, and only the
    ratios to BC-OH compare.
    """
    groups = groups_of(merged, "pos", protocol)
    if not groups:
        return ""
    same_scale = in_fca_family(protocol)
    known = known_methods(merged)
    lines = ["| method | " + " | ".join(f"{tasks.get(m['env']).title}: paper | {tasks.get(m['env']).title}: ours"
                                       for m in groups) + " |", "|---|" + "---:|" * (2 * len(groups))]
    # the paper's FCA is the FCA paper's adversary with its information bottleneck: ours with it where it ran
    # (`fca-ib`), else the adversary alone as the FCA code ships it (`fca`); the row names which
    fca = "fca-ib" if any(method_rows(m, "fca-ib") for m in groups) else "fca"
    ours = [{"bc-so": best_of(method_rows(m, "bc-so")), "bc-oh": best_of(method_rows(m, "bc-oh")), "fca": best_of(method_rows(m, fca)),
             "ours": paper_step_row(m)} for m in groups]
    for method in PAPER_TABLE5:
        cells = []
        for m, mine in zip(groups, ours):
            paper, paper_bcoh = PAPER_TABLE5[method][m["env"]], PAPER_TABLE5["bc-oh"][m["env"]]
            row, bcoh = mine[method], mine["bc-oh"]
            cells.append(f"{paper:,} ({paper / paper_bcoh:.2f}×)")
            spread = f" ± {row['return_std']:,.0f}" if same_scale and row is not None else ""
            cells.append("—" if row is None or bcoh is None else
                         f"{row['return_mean']:,.0f}{spread} ({row['return_mean'] / bcoh['return_mean']:.2f}×)")
        name = "Ours, step THR 10% W 5" if method == "ours" else label(known, fca if method == "fca" else method)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    if same_scale:
        lines.append("| expert | " + " | ".join(
            "not published | " + ("—" if m["expert"]["return_mean"] is None else f"{m['expert']['return_mean']:,.0f}")
            for m in groups) + " |")
    return "\n".join(lines) + "\n"


def grid_table(m: dict) -> str:
    """Every configuration: return and % of expert (a task judged by a rate, its reward not its measure: the rate
    in %)."""
    rows = list(m["summary"])
    best = best_of([r for r in rows if r["n_seeds"]])
    rate = is_rate(m)
    heads = [f"{m['metric']} %"] if rate else ["return", "% of expert"]
    lines = ["| method | hparams | seeds | " + " | ".join(heads) + " |", "|---|---|---:|" + "---:|" * len(heads)]
    for r in rows:
        hp = ", ".join(f"{k} {v:g}" for k, v in r["hparams"].items()) or "—"
        lab = label(m["methods"], r["method"])
        ok = r["n_seeds"] and (not rate or r.get("normalized_mean") is not None)
        if not ok:
            lines.append(f"| {lab} | {hp} | {r['n_seeds']} | failed |" + ("" if rate else " |"))
            continue
        mark = "**" if r is best else ""
        if rate:
            cells = [f"{mark}{r['normalized_mean']:.1f} ± {r['normalized_std']:.1f}{mark}"]
        else:
            cells = [f"{mark}{r['return_mean']:,.1f} ± {r['return_std']:,.1f}{mark}",
                     f"{r['normalized_mean']:.1f}" if r.get("normalized_mean") is not None else "—"]
        lines.append(f"| {mark}{lab}{mark} | {hp} | {r['n_seeds']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def loss_table(m: dict) -> str:
    """The paper's Table 3: mean over seeds of the per-sample loss, all / changepoint / copycat, train / val."""
    keys = [(s, k) for s in ("train", "val") for k in ("unweighted", "changepoint", "copycat")]
    lines = ["| method | " + " | ".join(f"{s}: {'all' if k == 'unweighted' else k}" for s, k in keys) + " |",
             "|---|" + "---:|" * len(keys)]
    for lab, runs in loss_rows(m):
        vals = [sum(r["losses"][s][k] for r in runs) / len(runs) for s, k in keys]
        lines.append(f"| {lab} | " + " | ".join(f"{v:.4f}" for v in vals) + " |")
    return "\n".join(lines) + "\n"


def copycat_table(m: dict) -> str | None:
    """The copycat diagnostics of every configuration that has them (None if no run does).

    Per configuration, the mean over seeds of each seed's mean over evaluation episodes of
    `rollout_ape` (the APE of the policy's own actions, ÷ the training set's mean APE) and
    `imitation_error` (Σ_d (a − a*)² against the expert's action on the policy's own states).
    """
    groups = copycat_groups(m)
    if not groups:
        return None
    expert = expert_ape(m)
    unit = display_metric(m)[1] if display_metric(m)[0] == "normalized" else "% of expert"
    lines = ["| method | hparams | seeds | rollout APE (÷ training mean) | imitation error on own states | "
             f"{unit} |", "|---|---|---:|---:|---:|---:|"]
    if expert is not None:
        lines.append(f"| expert (validation demonstrations) | — | — | {expert:.2f} | 0 | "
                     f"{'—' if is_rate(m) else 100} |")
    for (method, hp), runs in groups.items():
        mean = lambda k: sum(r["eval"][k] for r in runs) / len(runs)  # noqa: E731
        norm = f"{mean('normalized'):.1f}" if all("normalized" in r["eval"] for r in runs) else "—"
        hps = ", ".join(f"{k} {v:g}" for k, v in hp) or "—"
        lines.append(f"| {label(m['methods'], method)} | {hps} | {len(runs)} | {mean('rollout_ape'):.3f} | "
                     f"{mean('imitation_error'):.4f} | {norm} |")
    return "\n".join(lines) + "\n"


# What each column of a diagnostics table shows (`diagnostics_table`), one line each, under its first table.
DIAGNOSTICS_COLUMNS = (
    "seeds: the configuration's trained policies; % of expert: their mean",
    "embedding ratio: a probe's held-out MSE predicting the expert's previous action a_{t−1} from the frozen "
    "policy's embedding ÷ the same probe's from a_t alone, median over seeds (their range in brackets); below 1 "
    "the embedding holds a_{t−1} beyond what a_t gives",
    "velocity 1 − R²: the probe's held-out MSE predicting the true joint velocity from the embedding ÷ the "
    "velocity's variance, median over seeds; near 0 the policy extracts velocity (— where the data has none)",
    "predictability ratio: ψ's held-out MSE on the policy's own rollout actions ÷ on the expert's rollouts (as "
    "many steps), median over seeds (range); below 1 the policy's actions are more predictable than the expert's",
    "verdict: the seeds judged copycat / the seeds whose diagnostics could be read (— where none could)",
    "embedding ÷ state (where the files record it): the embedding probe's MSE ÷ the same probe's from the true "
    "state at t (the expert's observation: joint positions and velocities), median (range). The expert's "
    "previous action follows from the previous state, which the current one nearly fixes, so reading the state "
    "well carries a_{t−1} without copying it; but the small probe reads a trained embedding (a feature made to "
    "predict a_t, which a_{t−1} is close to) more easily than the raw state, so a ratio below 1 is expected even "
    "without a history: compare it with BC-SO's, which has none",
)


def _ratio(s: Spread | None, with_range: bool = True) -> str:
    """`"0.412 (0.301–0.52)"`: a ratio's median over seeds and, with `with_range` and ≥ 2 seeds, their range."""
    if s is None:
        return "—"
    return f"{s.median:.3g}" + (f" ({s.low:.3g}–{s.high:.3g})" if with_range and s.n > 1 else "")


def _verdicts(d: PolicyDiagnostics) -> str:
    """`"copycat 2/5"`: seeds judged copycat / seeds read; "—" where none could be read."""
    return "—" if not d.read else f"copycat {d.copycats}/{d.read}"


def _diagnostics_cells(row: DiagnosticsRow) -> list[str]:
    d = row.diagnostics
    return [", ".join(f"{k} {v:g}" for k, v in row.hparams.items()) or "—", str(row.seeds),
            "—" if row.normalized is None else f"{row.normalized:.1f}", _ratio(d.embedding),
            _ratio(d.velocity, with_range=False), _ratio(d.predictability), _verdicts(d)]


def diagnostics_table(rows: list[tuple[tuple[str, ...], DiagnosticsRow]], heads: tuple[str, ...] = ("method",),
                      unit: str = "% of expert") -> str:
    """Copycat diagnostics per configuration: seeds, % of expert, embedding ratio (median and range over seeds),
    velocity 1 − R² (median), predictability ratio (median and range) and the verdict count.

    Args:
      rows: `(leading cells, row)`, the leading cells one per `heads` (`("Hopper", "fca", "BC-OH")`).
      heads: the leading columns' headings (the method, and in the recipe table the task and recipe first).
      unit: the heading of the % of expert column (a task judged by a rate: that rate in %).
    """
    state = any(row.diagnostics.state is not None for _, row in rows)   # files from before it: no column
    lines = ["| " + " | ".join(heads) + f" | hparams | seeds | {unit} | embedding ratio | velocity 1 − R² | "
             "predictability ratio | verdict |" + (" embedding ÷ state |" if state else ""),
             "|" + "---|" * (len(heads) + 1) + "---:|" * 5 + "---|" + ("---:|" if state else "")]
    lines += ["| " + " | ".join([*lead, *_diagnostics_cells(row)]) + " |"
              + (f" {_ratio(row.diagnostics.state)} |" if state else "") for lead, row in rows]
    return "\n".join(lines) + "\n"


def thresholds_line(thresholds: list[dict]) -> str:
    """The copycat verdict's criteria as the files record them (`analysis.diagnostics_thresholds`), in one line."""
    def both(t: dict) -> str:
        return " and ".join(f"{name} ≤ " + (f"{t[key]:g}" if isinstance(t.get(key), (int, float)) else "?")
                            for name, key in (("embedding ratio", "embedding_ratio"),
                                              ("predictability ratio", "predictability_ratio")))

    fixed = "thresholds fixed before any result, `ape_jax.diagnostics.THRESHOLDS`"
    if not thresholds:
        return "Copycat = both ratios at or below their thresholds, per seed; the files record no thresholds."
    if len(thresholds) == 1:
        return f"Copycat = {both(thresholds[0])}, both, per seed ({fixed})."
    return (f"Copycat = both ratios at or below their thresholds, per seed ({fixed}); the files record different "
            "ones: " + "; ".join(both(t) for t in thresholds) + ".")


def _absent_lines(rows: list[tuple[tuple[str, ...], DiagnosticsRow]], heads: tuple[str, ...]) -> list[str]:
    """One bullet per configuration with seeds the diagnostics could not read (shown "—" in the table), with the
    recorded reason: `"- BC-SO (Hopper, recipe fca): no diagnostics for 1 of 5 seeds: …"`."""
    out = []
    for lead, row in rows:
        where = [f"recipe {v}" if h == "recipe" else v for h, v in zip(heads, lead) if h != "method"]
        where += [", ".join(f"{k} {v:g}" for k, v in row.hparams.items())] if row.hparams else []
        for why, n in row.diagnostics.absent:
            out.append(f"- {row.label}" + (f" ({', '.join(where)})" if where else "")
                       + f": no diagnostics for {n} of {row.seeds} seed{'s' * (row.seeds != 1)}: {why}")
    return out


def diagnostics_lines(rows: list[tuple[tuple[str, ...], DiagnosticsRow]], thresholds: list[dict], intro: str,
                      explained: bool, heads: tuple[str, ...] = ("method",), unit: str = "% of expert") -> list[str]:
    """A diagnostics table with its caption, the column explanations (unless `explained` above), the thresholds
    once under it and the seeds it could not read; nothing without rows."""
    if not rows:
        return []
    if explained:
        out = [intro.rstrip(":") + " (the columns as explained under the first such table above):", ""]
    else:
        out = [intro, "", *(f"- {c}" for c in DIAGNOSTICS_COLUMNS), ""]
    absent = _absent_lines(rows, heads)
    out += [diagnostics_table(rows, heads, unit), thresholds_line(thresholds), ""]
    return out + (absent + [""] if absent else [])


def diagnostics_section(m: dict, explained: bool) -> list[str]:
    """Group `m`'s copycat diagnostics per configuration (`analysis.diagnostics_rows`); nothing for a group whose
    files predate them."""
    rows = [((r.label,), r) for r in diagnostics_rows(m)]
    unit = display_metric(m)[1] if display_metric(m)[0] == "normalized" else "% of expert"
    return diagnostics_lines(rows, diagnostics_thresholds(m["sources"]),
                             "Copycat diagnostics per trained policy (`ape_jax.diagnostics`), from its embedding "
                             "and its own rollouts:", explained, unit=unit)


def training_table(m: dict) -> list[str]:
    """Group `m`'s configurations over training (`Budget.eval_at`): per configuration and iteration, % of expert
    with its 95% bootstrap interval over seeds, the training loss, the copycat diagnostics' medians and the
    verdict count; nothing for a group evaluated at the end only."""
    points = training_points(m)
    if not points:
        return []
    unit = display_metric(m)[1] if display_metric(m)[0] == "normalized" else "% of expert"
    lines = ["The same policies over training (the runs also evaluated at `budget.eval_at`'s iterations, on the "
             "same episodes, with the same diagnostics; a run's learning-rate schedule is its whole run's):", "",
             f"| method | hparams | iteration | {unit} [95% CI] | training loss | embedding ratio | "
             "predictability ratio | verdict |", "|---|---|---:|---:|---:|---:|---:|---|"]
    for p in points:
        hps = ", ".join(f"{k} {v:g}" for k, v in p.hparams.items()) or "—"
        loss = "—" if p.train_loss is None else f"{p.train_loss:.4g}"
        lines.append(f"| {p.label} | {hps} | {p.iteration:,} | {_pct_cell(p.normalized)} | {loss} | "
                     f"{_ratio(p.diagnostics.embedding)} | {_ratio(p.diagnostics.predictability)} | "
                     f"{_verdicts(p.diagnostics)} |")
    return [*lines, ""]


SENSITIVITY = Key("walker2d", "pos", BRAX)  # the group the sensitivity study ran in (its committed file is brax's)


def sensitivity_table(merged: dict) -> str | None:
    """The sensitivity study on Walker2d (states, `SENSITIVITY`'s protocol): τ ∈ {0.1, 0.2, 0.5} and W ∈ {4, 5, 6}
    at THR 10%, with the paper's."""
    m = merged.get(SENSITIVITY)
    if m is None:
        return None
    tau, w = sensitivity(m)
    if not any(r for _, r in tau + w):
        return None
    lines = ["| setting | ours: Walker2d return | ours: % of expert | paper |", "|---|---:|---:|---:|"]
    for t, r in tau:
        paper = f"Walker2d {PAPER_SENSITIVITY_TAU[t][0]} ± {PAPER_SENSITIVITY_TAU[t][1]}"
        lines.append(f"| softmax τ {t:g} | {_cell(r).split(' (')[0]} | {_norm_cell(r)} | {paper} |")
    for x, r in w:
        lines.append(f"| step THR 10%, W {x:g} | {_cell(r).split(' (')[0]} | {_norm_cell(r)} | "
                     f"driving {PAPER_SENSITIVITY_W[x]}% success |")
    for name, group in (("τ", tau), ("W", w)):
        got = [r for _, r in group if r is not None]
        if len(got) == len(group):
            spread = max(r["return_mean"] for r in got) - min(r["return_mean"] for r in got)
            std = max(r["return_std"] for r in got)
            word = "within" if spread <= std else "beyond"
            lines.append(f"\nOver {name}: the means span {spread:,.0f}, {word} the largest std over seeds ({std:,.0f}).")
    return "\n".join(lines) + "\n"


def longer_table(rows, base: dict, longer: dict) -> str:
    """`analysis.longer_runs`' rows of one group: each configuration at the base budget and at the longer one."""
    its = lambda m: f"{m['sources'][0].config['iterations']:,} iterations"  # noqa: E731
    lines = [f"| {longer['title']}: configuration | {its(base)} | seeds | {its(longer)} | seeds |",
             "|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r.label} | {_cell(r.base)} | {r.base['n_seeds']} | {_cell(r.longer)} | "
                     f"{r.longer['n_seeds']} |")
    return "\n".join(lines) + "\n"


def bootstrap_table(rows: list[Difference]) -> str:
    """The rows of `bootstrap_rows` as a table: per group and comparison, seeds, difference of means, 95% CI,
    verdict."""
    lines = ["| task | comparison | seeds | difference | 95% CI | verdict |", "|---|---|---:|---:|---:|---|"]
    lines += [f"| {d.title} | {d.label} | {d.ci.n_a} / {d.ci.n_b} | {d.ci.diff:+,.0f} ({d.unit}) | "
              f"[{d.ci.low:+,.0f}, {d.ci.high:+,.0f}] | {verdict(d.ci, d.a, d.b)} |" for d in rows]
    return "\n".join(lines) + "\n"


def _top(y: np.ndarray | None, fraction: float = 0.0) -> str:
    """The share of a batch's weight its heaviest sample (`fraction` 0) or heaviest `fraction` carry, in %."""
    if y is None:
        return "—"
    return f"{100 * y[max(1, round(fraction * len(y))) - 1]:.0f}%"


def weights_table(shares: list[WeightShares]) -> str:
    """The heaviest sample's and the heaviest 10%'s share of a batch's weight, per group and setting, with the
    weights computed on each APE scale (`analysis.APE_SCALES`)."""
    raw, by_mean = APE_SCALES["none"], APE_SCALES["mean"]
    lines = [f"| task | weighting | {raw}: heaviest sample's share | heaviest 10%'s | {by_mean}: heaviest sample's "
             "share | heaviest 10%'s |", "|---|---|---:|---:|---:|---:|"]
    for w in shares:
        for lab, y_raw, y_mean in w.series:
            lines.append(f"| {w.title} | {lab} | {_top(y_raw)} | {_top(y_raw, 0.1)} | {_top(y_mean)} | "
                         f"{_top(y_mean, 0.1)} |")
    return "\n".join(lines) + "\n"


def trained_on(w: WeightShares) -> str:
    """Which APE scale a group's softmax runs trained on, and what dividing by the mean does to its APE."""
    text = f"{w.title}: its softmax runs trained with `normalization: {w.trained}`, on the {APE_SCALES[w.trained]}"
    if w.mean_ape > 0:
        how = "recorded as its scale" if w.mean_recorded else "estimated from the recorded quantiles"
        text += (f"; its raw training APE's mean, {how}, is {w.mean_ape:.3g}, so dividing by it multiplies the APE "
                 f"by {1 / w.mean_ape:,.3g}")
    return text + "."


def _map_cell(cell) -> str:
    return "—" if cell is None else f"{cell.mean:.1f} ± {cell.std:.1f}"


def copycat_map_table(maps: list[CopycatMap]) -> str:
    """The copycat map as one table: per task and frame skip, BC-SO, BC-OH and Ours (step THR 10% W 5) in % of
    expert (mean ± std over seeds), the seeds, BC-OH − BC-SO with its 95% CI, and expert − BC-OH."""
    names = [lab for lab, _, _ in MAP_METHODS]
    lines = ["| task | frame skip | training transitions | protocol | " + " | ".join(names) + " | seeds (" +
             " / ".join(n.split(",")[0] for n in names) + ") | BC-OH − BC-SO [95% CI] | expert − BC-OH |",
             "|---|---:|---:|---|" + "---:|" * (len(names) + 3)]
    for cm in maps:
        shown = {(r.frame_skip, r.train_transitions) for r in cm.rows}
        for r in cm.rows + [r for r in cm.data_rows if (r.frame_skip, r.train_transitions) not in shown]:
            history = "—" if r.history is None else f"{r.history:+.1f}"
            if r.history_ci is not None:
                history += f" [{r.history_ci.low:+.1f}, {r.history_ci.high:+.1f}]"
            train = "—" if r.train_transitions is None else f"{r.train_transitions:,}"
            lines.append(f"| {cm.title} | {r.frame_skip} | {train} | {r.protocol} | " + " | ".join(map(_map_cell, r.cells))
                         + " | " + " / ".join("—" if c is None else str(c.n) for c in r.cells) + f" | {history} | "
                         + ("—" if r.ceiling is None else f"{r.ceiling:.1f}") + " |")
    return "\n".join(lines) + "\n"


def _lift(points: float, unit: str = "points of expert") -> str:
    """`"lifts BC-OH 12.3 points of expert above BC-SO"`, or `"leaves BC-OH 4.0 ... below BC-SO"` when negative."""
    if points >= 0:
        return f"lifts BC-OH {points:.1f} {unit} above BC-SO"
    return f"leaves BC-OH {-points:.1f} {unit} below BC-SO"


def _ci(ci: Interval, fmt: str = "+.1f") -> str:
    return f"95% CI [{ci.low:{fmt}}, {ci.high:{fmt}}]"


def _significant(ci: Interval | None) -> bool:
    """Whether `ci` says its first arm is better: ≥ 2 seeds per arm and the interval above 0."""
    return ci is not None and min(ci.n_a, ci.n_b) >= 2 and ci.low > 0


def copycat_map_data_sentence(cm: CopycatMap) -> str | None:
    """At frame skip 1, how the history's benefit and BC-OH change with the training-set size (None: one size)."""
    rows = [r for r in cm.data_rows if r.history is not None]
    if len(rows) < 2:
        return None
    parts = [f"with {r.train_transitions:,} training transitions the history {_lift(r.history)}"
             + (f" ({_ci(r.history_ci)})" if r.history_ci else "") for r in rows]
    bcoh = [r for r in cm.data_rows if r.cells[1] is not None]
    text = f"{cm.title}, frame skip 1: " + "; ".join(parts) + "."
    if bcoh:
        text += " BC-OH reaches " + ", ".join(f"{r.cells[1].mean:.1f}% of expert with {r.train_transitions:,}"
                                               for r in bcoh) + "."
    return text


def copycat_map_sentence(cm: CopycatMap) -> str:
    """Where the history's benefit opens along the frame skips of one task's copycat map, from its numbers."""
    rows = [r for r in cm.rows if r.history is not None]
    if len(cm.rows) < 2:
        return copycat_map_data_sentence(cm) or f"{cm.title}: the map has one frame skip."
    if not rows:
        return f"{cm.title}: BC-SO and BC-OH did not both run at any frame skip, so the map cannot say."
    top, rest = rows[-1], rows[-2::-1]
    text = f"{cm.title}: at frame skip {top.frame_skip} the history {_lift(top.history)}" + (
        f" ({_ci(top.history_ci)})" if top.history_ci else "")
    for r in rest:
        words = f"lifts it {r.history:.1f} points" if r.history >= 0 else \
            f"leaves it {-r.history:.1f} points below BC-SO"
        text += f"; at frame skip {r.frame_skip} it {words}" + (f" ({_ci(r.history_ci)})" if r.history_ci else "")
    text += "."
    tested = [r for r in rows if r.history_ci is not None and min(r.history_ci.n_a, r.history_ci.n_b) >= 2]
    if tested:
        yes = [str(r.frame_skip) for r in tested if _significant(r.history_ci)]
        no = [str(r.frame_skip) for r in tested if not _significant(r.history_ci)]
        if not yes:
            text += " At no frame skip is BC-OH significantly above BC-SO."
        elif not no:
            text += " BC-OH is significantly above BC-SO at every frame skip."
        else:
            text += (f" BC-OH is significantly above BC-SO at frame skip {', '.join(yes)}, not at "
                     f"{', '.join(no)}.")
    gaps = [r for r in cm.rows if r.ceiling is not None]
    if gaps:
        text += " BC-OH's gap to the expert: " + ", ".join(
            f"{r.ceiling:.1f} points at frame skip {r.frame_skip}" for r in gaps) + "."
    data = copycat_map_data_sentence(cm)
    return text + (f" {data}" if data else "")


def _fmt(mean: float, std: float, prefix: str) -> str:
    return f"{mean:.1f} ± {std:.1f}%" if prefix == "normalized" else f"{mean:,.0f} ± {std:,.0f}"


_SETTING = {"step": lambda hp: f"THR {percent(hp['thr'])} W {hp['w']:g}", "softmax": lambda hp: f"τ {hp['tau']:g}"}


def paper_choices(m: dict) -> list[str]:
    """One sentence per weighting: is the paper's setting within one std over seeds of the grid's best?

    "Within one std" means the gap to the best is at most the larger of the two configurations' std over seeds.
    Where our APE was divided by its training-set mean, the softmax sentence also names the grid value
    nearest to the paper's τ carried over to that scale (the paper's τ acts on the raw APE).
    """
    prefix, _ = display_metric(m)
    pts = " points" if prefix == "normalized" else ""

    def near(chosen: dict, best: dict, rows: list[dict], kind: str) -> str:
        g = gap(chosen, best, prefix)
        if g.is_best:
            return f"{_fmt(*g.chosen, prefix)}, the best of the {len(rows)} {kind} settings"
        where = (f"within one std over seeds ({g.noise:.1f}) of the best" if g.within else
                 f"more than one std over seeds ({g.noise:.1f}) below the best: not near it")
        return (f"{_fmt(*g.chosen, prefix)} vs the best, {_SETTING[kind](best['hparams'])}, {_fmt(*g.best, prefix)}: "
                f"{g.gap:.1f}{pts} lower, {where}")

    out = []
    for c in choices(m):
        text = f"{c.kind.capitalize()}, the paper's {_SETTING[c.kind](c.paper)}: " + (
            "not run" if c.chosen is None else near(c.chosen, c.best, c.rows, c.kind)) + "."
        if c.closest is not None:
            text += (f" But our τ acts on the APE divided by its training-set mean ({c.scale:.4f}) and the paper's on "
                     f"the raw APE, so its τ {c.paper['tau']:g} is about τ {c.equivalent:.1f} here (roughly: the "
                     f"paper's APE scale is not ours); the nearest grid value, τ {c.closest['hparams']['tau']:g}: "
                     f"{near(c.closest, c.best, c.rows, c.kind)}.")
        out.append(text)
    return out


def _words(ci: Interval, a: str, b: str, better: str, worse: str) -> str:
    """A verdict (`analysis.verdict`) in the plain reading's words: `better` if `a` is, `worse` if `b` is."""
    v = verdict(ci, a, b)
    if v == f"{a} better":
        return better
    if v == f"{b} better":
        return worse
    return "not significant: these seeds cannot tell them apart" if v.startswith("not significant") else v


def plain_reading(merged: dict, maps: list[CopycatMap]) -> list[str]:
    """Does keyframe weighting help where the history does not? One paragraph per task with results under the
    paper's protocol (`fca`; tasks without any get none), every number from the results:

    - the history: BC-OH − BC-SO under fca with its CI; BC-OH not significantly above BC-SO means the history
      adds nothing these seeds can see, the return signature the paper attributes to copycat; whether BC-OH
      copies is the diagnostics' to say (BC-OH's verdicts where its runs record them, else that they were not
      measured), never inferred from returns;
    - Ours − BC-OH at the paper's step setting, and at the best of our step and softmax grids (selected after
      the fact on the evaluation returns, so optimistic), each with its CI's verdict;
    - where the task has a copycat map or brax results, the history's benefit (in points of % of expert) at
      the largest frame skip and under Brax's own settings, against the fca frame skip's.
    """
    maps_of = {(cm.env, cm.obs): cm for cm in maps}
    out = []
    for key, m in ordered(merged):
        if key.protocol != FCA or key.budget is not None:
            continue
        unit = bootstrap_unit(m)[1]
        number = ",.0f"
        text = [f"**{group_title(key, m['protocol'], with_protocol=False)}.**"]
        history = history_difference(m)
        copycat = None
        if history is None:
            text.append("BC-SO and BC-OH did not both run under fca, so these results cannot say whether the "
                        "history helps.")
        elif min(history.n_a, history.n_b) < 2:
            text.append(f"Under fca BC-OH − BC-SO is {history.diff:+{number}} ({unit}), with fewer than 2 seeds "
                        "per arm: no verdict on the history.")
        else:
            copycat = not _significant(history)
            where = ("significantly above" if not copycat else
                     "significantly below" if history.high < 0 else "not significantly above")
            meaning = ("the history helps" if not copycat else
                       "the history hurts, the return signature the paper attributes to copycat" if history.high < 0
                       else "the history adds nothing, the return signature the paper attributes to copycat")
            text.append(f"Under fca BC-OH is {where} BC-SO ({history.diff:+{number}} {unit}, {_ci(history, '+,.0f')}):"
                        f" {meaning}.")
        text.append(_bcoh_diagnosed(m))
        ours = ours_differences(m)
        paper = next(((row, ci) for _, row, ci in ours if row["method"] == "ours-step"
                      and row["hparams"] == PAPER_STEP), None)
        if paper is None:
            text.append(f"Ours at the paper's step setting (THR {percent(PAPER_STEP['thr'])}, W {PAPER_STEP['w']:g}) "
                        "did not run under fca, or BC-OH did not.")
        else:
            ci = paper[1]
            text.append(f"Ours at the paper's step setting (THR {percent(PAPER_STEP['thr'])}, W {PAPER_STEP['w']:g}) "
                        f"− BC-OH: {ci.diff:+{number}} {unit} ({_ci(ci, '+,.0f')}): "
                        f"{_words(ci, 'Ours', 'BC-OH', 'keyframe weighting beats BC-OH', 'BC-OH beats it')}.")
        grids = [(row, ci) for lab, row, ci in ours[1:]]
        best_row = best_of([row for row, _ in grids])
        if len(method_rows(m, "ours-step")) + len(method_rows(m, "ours-softmax")) <= 1:
            best_row = None   # no grid ran beside the paper's setting: nothing was selected
        if best_row is not None and paper is not None and best_row is paper[0]:
            text.append("The best of our step and softmax grids is that same setting.")
        elif best_row is not None:
            ci = next(c for row, c in grids if row is best_row)
            kind = "softmax" if best_row["method"] == "ours-softmax" else "step"
            text.append(f"The best of our step and softmax grids, {kind} {_SETTING[kind](best_row['hparams'])} "
                        f"(selected after the fact on these evaluation returns, so optimistic): "
                        f"{ci.diff:+{number}} {unit} ({_ci(ci, '+,.0f')}): "
                        f"{_words(ci, 'Ours', 'BC-OH', 'it beats BC-OH', 'BC-OH beats it')}.")
        if copycat and paper is not None:
            outcome = {"Ours better": "beats BC-OH", "BC-OH better": "does worse than BC-OH"}.get(
                verdict(paper[1]), "does not detectably beat BC-OH")
            text.append(f"So where the history does not help, keyframe weighting at the paper's setting {outcome} on "
                        "these seeds.")
        extras = extra_methods({key: m})
        others = [(lab, ci) for lab, row, ci in versus_bcoh(m, extras, known_methods(merged))
                  if row is not None and row["method"] in extras and ci is not None and min(ci.n_a, ci.n_b) >= 2]
        if others:
            def listed(pairs):
                return ", ".join(f"{lab} ({ci.diff:+{number}}, {_ci(ci, '+,.0f')})" for lab, ci in pairs)

            above = [(lab, ci) for lab, ci in others if ci.low > 0]
            below = [(lab, ci) for lab, ci in others if ci.high < 0]
            level = [lab for lab, ci in others if ci.low <= 0 <= ci.high]
            parts = [f"significantly above: {listed(above) if above else 'none'}"]
            if below:
                parts.append(f"significantly below: {listed(below)}")
            if level:
                parts.append(f"not significantly different: {', '.join(level)}")
            text.append(f"The other methods under fca against BC-OH (in {unit}): " + "; ".join(parts) + ".")
        contrast = []
        cm = maps_of.get((key.env, key.obs))
        here = cm.at(m["protocol"].get("frame_skip")) if cm else None
        top = next((r for r in reversed(cm.rows) if r.history is not None), None) if cm else None
        if top is not None and here is not None and here.history is not None and top is not here:
            contrast.append(f"at frame skip {top.frame_skip} the history {_lift(top.history)}"
                            + (f" ({_ci(top.history_ci)})" if top.history_ci else "")
                            + f", against {here.history:+.1f} at frame skip {here.frame_skip}"
                            + (f" ({_ci(here.history_ci)})" if here.history_ci else ""))
        brax = merged.get(Key(key.env, key.obs, BRAX))
        brax_history = None if brax is None else history_difference(brax, "normalized", 1.0)
        if brax_history is not None:
            contrast.append(f"under Brax's own frame skip (brax) {'it' if contrast else 'the history'} "
                            f"{_lift(brax_history.diff)} ({_ci(brax_history)})")
        if contrast:
            text.append("In % of expert: " + "; ".join(contrast) + ".")
        out.append(" ".join(text))
    return out


def _bcoh_diagnosed(m: dict) -> str:
    """Whether group `m`'s BC-OH copies, by its copycat diagnostics: the seeds judged copycat and the median ratios,
    or that its runs record none (files from before the diagnostics)."""
    row = best_of(method_rows(m, "bc-oh"))
    d = policy_diagnostics([r for r in m["runs"] if row is not None and r["method"] == "bc-oh"
                            and r["hparams"] == row["hparams"]])
    if not d.read:
        return ("BC-OH's policies here were not diagnosed (their files predate the copycat diagnostics), so whether "
                "it copies is not measured.")
    return (f"BC-OH's copycat diagnostics judge {d.copycats} of {d.read} seeds copycat (median embedding ratio "
            f"{_ratio(d.embedding, with_range=False)}, predictability ratio {_ratio(d.predictability, with_range=False)}).")


def _grid_name(m: dict) -> str:
    """A group's grid figure: `grid-hopper.png` (brax), `grid-hopper-image.png`, `grid-hopper-fca-fs2.png`."""
    return f"grid-{file_stem(m)}.png"


def _protocol_provenance(r: results_lib.Results) -> str:
    """The protocol a results file ran under, as its provenance line says it."""
    if not r.protocol:
        return f"protocol {BRAX} (not recorded: results schema 1 predates protocols; Brax's own settings)"
    p = r.protocol
    skip, own = p.get("frame_skip"), p.get("standard_frame_skip")
    parts = [] if skip is None else [f"frame skip {skip}" + (f" (the environment's own: {own})"
                                                             if own is not None and own != skip else "")]
    if p.get("episode_length"):
        parts.append(f"{p['episode_length']:,}-step episodes")
    if p.get("train_transitions"):
        parts.append(f"{p['train_transitions']:,} training transitions")
    return f"protocol {p.get('name') or BRAX}" + "".join(f", {x}" for x in parts)


def _rebuilt_command(r: results_lib.Results) -> str:
    """The sweep command of a file that does not record its own (schema 1, or a sweep run from Python)."""
    from ape_jax.pipeline.presets import BUDGETS, resolve

    cfg = r.config
    cmd = f"python -m experiments.sweep --env {r.env} --obs {r.obs} --preset {r.preset}"
    if cfg.get("methods") != list(methods_lib.default()):
        cmd += f" --methods {','.join(cfg['methods'])}"
    # the budget and the grids of its preset (schema 1/2 files ran the mlp recipe, whose grids every recipe shares)
    preset = resolve(r.env, r.obs, preset=r.preset, recipe="mlp") if r.preset in BUDGETS else None
    for key, flag in (("iterations", "--iterations"), ("seeds", "--seeds"), ("eval_episodes", "--eval-episodes")):
        if preset is not None and cfg.get(key) != getattr(preset.budget, key):
            cmd += f" {flag} {cfg[key]}"
    if preset is not None and "step_grid" in cfg and [list(g) for g in preset.recipe.step_grid] != cfg["step_grid"]:
        cmd += " --step-grid " + ",".join(f"{thr:g}:{w:g}" for thr, w in cfg["step_grid"])
    if preset is not None and "softmax_grid" in cfg and list(preset.recipe.softmax_grid) != cfg["softmax_grid"]:
        cmd += " --softmax-grid " + ",".join(f"{tau:g}" for tau in cfg["softmax_grid"])
    return cmd


def provenance(r: results_lib.Results) -> str:
    """The command, protocol and setting one results file came from.

    The command is the one the file records (schema 2), shell-quoted. A file
    that records none is given the command rebuilt from its settings, and says
    why: schema 1 files (upgraded on load: no command, no protocol) predate
    schema 2, whose seeds are derived from each run's identity; a schema 2
    file without a command came from a sweep run from Python.
    """
    cfg = r.config
    if r.command is not None:
        cmd = f"`{shlex.join(r.command)}`"
    elif not r.protocol:
        cmd = (f"`{_rebuilt_command(r)}` (rebuilt from its settings: the file predates results schema 2, written "
               "before seeds were derived from run identity: its numbers came from position-based keys)")
    else:
        cmd = f"`{_rebuilt_command(r)}` (rebuilt from its settings: the sweep ran from Python)"
    s, t = r.system or {}, r.timing or {}
    machine = s.get("machine") or "machine not recorded in the file"
    commit = f"`{s.get('commit')}`" + (" with uncommitted changes" if s.get("dirty") else "")
    line = (f"{cmd} — {cfg['iterations']:,} iterations, {cfg['seeds']} seeds, {cfg['eval_episodes']} evaluation "
            f"episodes; {_protocol_provenance(r)}; commit {commit}, jax {s.get('jax')} ({s.get('backend')}, "
            f"{s.get('devices')} device(s)), {machine}; {t.get('total_s', 0):,.0f} s in all"
            + (" (resumed after an interruption: the last process's time only)" if t.get("resumed") else ""))
    if t.get("peak_rss_mb"):
        line += f", peak resident memory {t['peak_rss_mb'] / 1024:.1f} GB"
    width = ((r.settings or {}).get("budget") or {}).get("width")
    line += (f"; {width} configuration(s) per device per call (`budget.width`)" if width else
             "; each program vmapped whole (before `budget.width`: its numbers depend on what trained beside them)")
    chain, again = [], r.reevaluated
    while again:  # the latest evaluation first, each earlier one under "previous"
        chain.append(again)
        again = again.get("previous")
    added = [(", ".join(f"`{f}`" for f in a["fields"]), (a.get("system") or {}).get("commit"))
             for a in reversed(chain) if a.get("fields")]
    if added:
        (fields, commit), *later = added
        line += f"; {fields} added later by `python -m experiments.evaluate` (commit `{commit}`"
        line += "".join(f"), then {fields} (commit `{commit}`" for fields, commit in later)
        line += ", every recorded number reproduced)"
    return line


def _pct_cell(cell) -> str:
    return "—" if cell is None else f"{cell.mean:.1f} [{cell.low:.1f}, {cell.high:.1f}]"


def _diff_cell(ci: Interval | None) -> str:
    if ci is None:
        return "—"
    text = f"{ci.diff:+.1f} [{ci.low:+.1f}, {ci.high:+.1f}]"
    return f"**{text}**" if _significant(ci) else text


def recipe_section(merged: dict) -> list[str]:
    """"The paper's recipe": per task, every method under each recipe of one protocol, fca − mlp, the within-recipe
    differences the paper's question turns on, and every FCA setting that ran (the α sensitivity where several α
    did) with its adversary's loss beside the reference predictor's."""
    groups = recipe_groups(merged)
    if not groups:
        return []
    out = ["### The paper's recipe: the FCA code's network and optimiser against the project's first", "",
           "The same protocol, data, budget, seeds and evaluation episodes; only the recipe differs. `mlp`: the "
           "project's first recipe (no normalisation, Flax's default init, Adam β1 0.9, batch 128). `fca`: the FCA "
           "code's (BatchNorm after each encoder layer, LeakyReLU on the embedding, xavier-uniform init, Adam β1 "
           "0.5, batch 64; `ape_jax.pipeline.presets.RECIPES`). Each cell: % of expert, the mean over seeds with "
           "its 95% percentile bootstrap interval; fca − mlp: the difference of those means in points, with its "
           "interval, bold where it excludes 0. FCA rows are at the task's α (the FCA code's).", ""]
    told = False
    for (env, obs, setting), recipes in groups.items():
        rows = recipe_rows(recipes)
        names = [r for r in ("mlp", "fca") if r in recipes] + [r for r in recipes if r not in ("mlp", "fca")]
        title = tasks.get(env).title + ("" if obs == "pos" else f" ({obs})")
        out += [f"**{title}**, protocol {setting}:", "",
                "| method | " + " | ".join(f"recipe {n}" for n in names) + " | fca − mlp |",
                "|---|" + "---:|" * (len(names) + 1)]
        out += [f"| {r.label} | " + " | ".join(_pct_cell(r.cells.get(n)) for n in names) + f" | {_diff_cell(r.difference)} |"
                for r in rows]
        out += [""]
        lines = []
        for n in names:
            cells = {r.label: r.cells.get(n) for r in rows}
            for a, b in (("BC-OH", "BC-SO"), ("Ours, step THR 10% W 5", "BC-OH"), ("FCA (TCA)", "BC-OH"),
                         ("FCA (TCA + IB)", "BC-OH")):
                if cells.get(a) is not None and cells.get(b) is not None:
                    ci = bootstrap_difference(cells[a].seeds, cells[b].seeds)
                    lines.append(f"recipe {n}: {a} − {b} {_diff_cell(ci)} ({verdict(ci, a, b)})")
        if lines:
            out += [f"- {line}" for line in lines] + [""]
        for n in names:
            alphas = alpha_rows(recipes[n])
            if alphas:
                intro = ("% of expert [95% bootstrap interval], and the adversary's final loss (its prediction of "
                         "a_{t−1} from the embedding and a_t) beside a reference predictor's from a_t alone, means "
                         "over seeds of each run's last 1% of iterations: an adversary at the reference's loss gets "
                         "nothing about a_{t−1} from the embedding." if not told else "as above.")
                told = True
                out += [f"FCA's settings on {title}, recipe {n}: {intro}", "",
                        "| method | hyperparameters | % of expert | adversary loss | reference loss |",
                        "|---|---|---:|---:|---:|"]
                out += [f"| {a.method} | {', '.join(f'{k} {v:g}' for k, v in a.hparams.items())} | "
                        f"{_pct_cell(a.cell)} | " + " | ".join("—" if v is None else f"{v:.4g}"
                                                               for v in (a.adversary, a.reference)) + " |"
                        for a in alphas]
                out += [""]
    sources = [src for recipes in groups.values() for m in recipes.values() for src in m["sources"]]
    out += diagnostics_lines([((title, n, r.label), r) for title, n, r in recipe_diagnostics(groups)],
                             diagnostics_thresholds(sources), "Copycat diagnostics per trained policy "
                             "(`ape_jax.diagnostics`), per task, recipe and configuration:", explained=False,
                             heads=("task", "recipe", "method"))
    return out


def build(files: list[results_lib.Results], figure_dir: pathlib.Path | None = None,
          base: pathlib.Path | None = None) -> tuple[str, dict[pathlib.Path, object]]:
    """The report's markdown and its figures, nothing written.

    Args:
      files: loaded results files (`experiments.report.load`).
      figure_dir: where the figures will be written; None draws none (the text says so).
      base: the folder the markdown's links are relative to (the `--out` file's); default the working folder.

    Returns:
      `(text, figures)`: the markdown, and `{path: matplotlib Figure}` to write with `experiments.report.figures.save_png`.
    """
    merged = merge(files)
    drawn: dict[pathlib.Path, object] = {}
    base = pathlib.Path.cwd() if base is None else pathlib.Path(base)

    def figure(name: str, alt: str, draw) -> list[str]:
        fig = draw() if figure_dir is not None else None
        if fig is None:
            return []
        path = pathlib.Path(figure_dir) / name
        if path in drawn:  # one file per figure (`analysis.file_stem`): never let one group's overwrite another's
            raise ReportError(f"two of the report's figures would be written to {path}; pass fewer results files")
        drawn[path] = fig
        return [f"![{alt}]({pathlib.Path(os.path.relpath(path.absolute(), base.absolute())).as_posix()})", ""]

    out = []
    selection = ("\"Best\" rows pick the configuration with the highest return on the evaluation episodes "
                 "(selection on the test episodes, as the paper's grid search does; optimistic).")
    cells = ("Return mean ± std over seeds (each seed's mean over the evaluation episodes), and in brackets the "
             "percentage of our expert's return, normalised against a random policy under the same protocol.")
    for protocol in protocols_of(merged, "pos"):
        groups = groups_of(merged, "pos", protocol)
        heading, details = protocol_heading(groups), protocol_details(groups)
        if protocol == FCA:
            out += [f"### MuJoCo-State, the paper's protocol ({FCA})" + (f": {heading}" if heading else ""), "",
                    "Positions only (velocities removed). " + cells + " " + selection
                    + (f" {details}" if details else ""), "", state_table(merged, "pos", protocol)]
            out += versus_section(merged, protocol)
            horizon = _agreed(_horizon(m["protocol"]) for m in groups)
            scale = (f"rewards summed over {horizon:,.0f} standard control steps of simulated time, as the paper's"
                     if horizon is not None else "rewards on the standard control step's scale, as the paper's")
            out += ["The supplement's Table 5 beside it, on the same scale (" + scale + "): each cell the mean "
                    "return, ours ± std over seeds, and in brackets the ratio to BC-OH of the same source. The "
                    "experts differ (the paper does not publish its expert's return), so the ratio is the "
                    "comparison that does not depend on them.", "", paper_table(merged, protocol)]
        elif protocol == BRAX:
            out += ["### MuJoCo-State, Brax's frame skip, where the history helps (the project's first results)", "",
                    "Positions only (velocities removed), with the environments' own frame skip and episode length. "
                    + cells + " " + selection + (f" {details}" if details else ""), "",
                    state_table(merged, "pos", protocol)] + versus_section(merged, protocol) + [
                    "Next to the supplement's Table 5 (its own experts, whose returns it does not give; its returns "
                    "are on another scale than these): mean returns, and in brackets each method's ratio to BC-OH "
                    "of the same source.", "", paper_table(merged, protocol)]
        elif not in_fca_family(protocol) and not any(m["protocol"].get("variant_of") for m in groups):
            # the fca family's other frame skips feed the copycat map instead, and the recipe variants
            # (`analysis.variant_name`) the recipe section
            out += [f"### MuJoCo-State, protocol {protocol}" + (f": {heading}" if heading else ""), "",
                    "Positions only (velocities removed). " + cells + " " + selection
                    + (f" {details}" if details else ""), "", state_table(merged, "pos", protocol)]
    out += recipe_section(merged)
    out += paper_budget_section(merged, figure)
    out += extended_map_section(merged, figure)
    explained = bool(recipe_diagnostics(recipe_groups(merged)))   # the recipe section explained the columns
    for protocol in protocols_of(merged, "image"):
        groups = groups_of(merged, "image", protocol)
        details = protocol_details(groups)
        out += ["### MuJoCo-Image" + ("" if protocol == BRAX else f", protocol {protocol}"), "",
                "As MuJoCo-State, from rendered frames (the image presets: see each file's provenance below)."
                + (f" {details}" if details else ""), "", state_table(merged, "image", protocol)]
    for key, m in ordered(merged):
        table = task_table(m)
        if table:
            task = tasks.get(key.env)
            title = group_title(key, m["protocol"], m["shows_protocol"], with_obs=key.obs != task.default_obs)
            paper = (f"; the paper's {m['metric']} rates beside (its own {task.title}, not ours)" if task.paper
                     else "")
            walls = [f"{src.timing['total_s'] / 60:,.0f} min" for src in m["sources"]
                     if (src.timing or {}).get("total_s")]
            machine = next(((src.system or {}).get("machine") for src in m["sources"] if src.system), None)
            wall = (f" Wall time of the run{'s' if len(walls) > 1 else ''}: {', '.join(walls)}"
                    + (f" ({machine})" if machine else "") + ", compile included." if walls else "")
            out += [f"### {title} (the supplement's Table 4 protocol)", "",
                    f"{task.title}'s own metrics per policy, mean ± std over seeds of each seed's mean over "
                    f"evaluation episodes, and in brackets the mean's 95% bootstrap interval over seeds"
                    + (f"; the {m['metric']} rate of all episodes pooled with its binomial (Wilson) interval"
                       if is_rate(m) else "") + f"{paper}." + wall,
                    "", table]
            reading = task_reading(m)
            if reading:
                out += [" ".join(reading), ""]
    if figure_dir is None:
        out += ["_Figures not drawn: the report was printed without `--figures DIR` (with `--out` they go to "
                "`figures/` next to it)._", ""]
    maps = copycat_map(merged)
    if maps:
        skips = sorted({r.frame_skip for cm in maps for r in cm.rows})
        out += ["### The copycat map: the history's benefit per frame skip", "",
                f"The paper's protocol ({FCA}) at frame skips {', '.join(map(str, skips))}: the same simulated time "
                "per episode and the same numbers of training and validation transitions, so the policies differ "
                "only in how often they act. Per frame skip, BC-SO, BC-OH and Ours (step THR "
                f"{percent(PAPER_STEP['thr'])} W {PAPER_STEP['w']:g}) in % of expert (mean ± std over seeds); BC-OH − "
                "BC-SO is what the history adds, in points of % of expert, with a 95% bootstrap CI over seeds; "
                "expert − BC-OH is how far BC-OH is from its ceiling (the expert, 100%). The paper reads copycat from a "
                "small or negative BC-OH − BC-SO (the history not helping); the copycat diagnostics test whether the "
                "policies copy (\"Where copycat appears: the map, extended\", where files record them)."
                + (" The rows at frame skip 1 with other training-set sizes (fca-train5k, fca-train80k) separate "
                   "the frame rate from how much of the task the data shows: 20,000 transitions at frame skip 1 "
                   "span a quarter of the simulated time 20,000 span at frame skip 4, and 80,000 span the same."
                   if any(cm.data_rows for cm in maps) else ""), ""]
        out += figure("copycat-map.png", "The copycat map: % of expert per frame skip",
                      lambda: figures.copycat_map_figure(maps))
        out += [copycat_map_table(maps)] + [f"- {copycat_map_sentence(cm)}" for cm in maps] + [""]
    boot = bootstrap_rows(merged)
    returns = figure("returns.png", "Return per method and environment", lambda: figures.returns_figure(merged))
    if boot or returns:
        out += ["### Differences over seeds: Ours − BC-OH, and BC-OH − BC-SO", ""] + returns
    if boot:
        seeds = min(min(d.ci.n_a, d.ci.n_b) for d in boot)
        rates = list(dict.fromkeys(f"{tasks.get(m['env']).title}: in {m['metric']} rate"
                                   for _, m in ordered(merged) if is_rate(m)))
        out += ["Per task and protocol, BC-OH − BC-SO (does the history help? the paper reads copycat from it not "
                "helping) "
                "and Ours − BC-OH, differences of mean return over seeds"
                + (f" ({'; '.join(rates)})" if rates else "") + ", with a 95% percentile bootstrap confidence "
                f"interval (each arm's seeds resampled with replacement, independently, {BOOTSTRAP_RESAMPLES:,} "
                f"times; numpy seed {BOOTSTRAP_SEED}). The best-step and best-softmax rows were selected after the "
                "fact on these same evaluation returns, so their differences are optimistic.", "",
                bootstrap_table(boot),
                f"Caveat: with {seeds} seed{'s' * (seeds != 1)} per arm each arm has only "
                f"{math.comb(2 * seeds - 1, seeds)} distinct resamples, so the interval is coarse, and at so few "
                "seeds the percentile bootstrap is too narrow (it under-covers): read \"better\" as a hint, and "
                "\"not significant\" as \"these seeds cannot tell\", not as evidence of no effect.", ""]
    reading = plain_reading(merged, maps)
    if reading:
        out += ["### Does keyframe weighting help where the history does not?", "",
                f"Read from the tables above, task by task, under the paper's protocol ({FCA}); differences of "
                "mean return over seeds with their 95% bootstrap CIs. The paper reads copycat from the history not "
                "helping; here that is only the return signature, and whether BC-OH copies is what its copycat "
                "diagnostics say, where its runs record them.", ""]
        out += [f"{paragraph}\n" for paragraph in reading]
    longer = longer_runs(merged)
    if longer:
        out += ["### Training longer", "",
                "Configurations trained again for more iterations than their preset's (with `--iterations`), "
                "beside the same configuration at the preset's budget: mean ± std over seeds of each seed's mean "
                "return, and % of expert. Their differences over seeds are in the bootstrap table above.", ""]
        out += [longer_table(rows, base, m) for m, base, rows in longer]
    sens = sensitivity_table(merged)
    if sens:
        out += ["### Sensitivity (the supplement's §4)", "",
                f"Walker2d (states, protocol {SENSITIVITY.protocol}), softmax τ and the step weight W at THR 10%, "
                "next to the paper's numbers (its W study was on CARLA driving, so only the pattern compares).", "",
                sens]
    shares = weight_shares(merged)
    extra = figure("curves.png", "Training curves", lambda: figures.curves_figure(merged)) + \
        figure("weights.png", "Weight concentration within a batch", lambda: figures.weights_figure(shares))
    if shares:
        extra += [weights_table(shares)] + [f"- {trained_on(w)}" for w in shares] + [""]
    if extra:
        out += ["### Training curves and weights", "",
                "From the results files that record them (runs since the training curve and the APE quantiles "
                "were added to `results.json`). Weights: batches of 128 drawn from each group's training APE "
                "distribution and weighted as the sweep does, `B·softmax(APE/τ)` or the step function; each curve "
                "is the share of a batch's total weight its k heaviest samples carry (uniform weights: the "
                "diagonal). A curve near 1 at k = 1 is a batch whose loss is one sample's. The softmax acts on "
                f"whichever APE a run trained on: the {APE_SCALES['none']}, or the {APE_SCALES['mean']}, which "
                "multiplies it by one over its mean (usually far more than 1) and so makes a τ ≤ 1 put nearly all "
                "of a batch's weight on one sample. Both are shown for every group, computed from its recorded "
                "quantiles; the step and uniform weights depend only on ranks and are the same on both.", ""] + extra
    for key, m in ordered(merged):
        protocol = f", protocol {protocol_words(m['protocol'])}" if m["shows_protocol"] else ""
        out += [f"### {tasks.get(key.env).title}, `{key.obs}` observations{protocol}: every configuration", ""]
        out += [f"- {provenance(r)}" for r in m["sources"]]
        out += ["", grid_table(m)]
        out += figure(_grid_name(m), f"{m['title']} grid search", lambda: figures.grid_figure(m))
        sentences = paper_choices(m)
        if sentences:
            unit = display_metric(m)[1]
            out += [f"Are the paper's settings near the best of our grid? (In {unit}; \"within one std\": "
                    "the gap to the best is at most the larger of the two settings' std over seeds.)", ""]
            out += [f"- {c}" for c in sentences] + [""]
        out += ["Loss analysis (the paper's Table 3; mean over seeds of the per-sample "
                "loss; changepoints = top 10% APE of each split):", "", loss_table(m)]
        copycat = copycat_table(m)
        if copycat:
            out += ["Copycat diagnostics, from the evaluation rollouts: how predictable each policy's own "
                    "actions are from its previous 9 (ψ's APE, ÷ the training set's mean APE; a policy that "
                    "repeats its last action scores below the expert), and how far its actions are from the "
                    "expert's on the states it visits itself:", "", copycat]
        diagnostics = diagnostics_section(m, explained)
        out += diagnostics + training_table(m)
        explained = explained or bool(diagnostics)
    return "\n".join(out), drawn


def _ratio_cell(rows: list[BudgetRow], r: BudgetRow, its: list[int]) -> str:
    """`"x"` of `r` at each of `its`, `"—"` where the point is missing; "/" between them."""
    return " / ".join("—" if (p := r.at(i)) is None or p.returns is None or (b := _bcoh_at(rows, i)) is None
                      else f"{p.returns.mean / b:.2f}×" for i in its)


def _bcoh_at(rows: list[BudgetRow], iteration: int) -> float | None:
    bcoh = next((r for r in rows if r.method == "bc-oh"), None)
    p = None if bcoh is None else bcoh.at(iteration)
    return None if p is None or p.returns is None or p.returns.mean == 0 else p.returns.mean


def _ratios(r: BudgetRow, its: list[int], field: str) -> str:
    return " → ".join("—" if (p := r.at(i)) is None else _ratio(getattr(p.diagnostics, field), with_range=False)
                      for i in its)


def _budget_reading(rows: list[BudgetRow], diffs: list[tuple[str, dict[int, Interval]]]) -> str:
    """One task's plain reading of the paper-budget table, from its numbers."""
    by = {r.method: r for r in rows}
    title = tasks.get(rows[0].env).title
    end = max(p.iteration for r in rows for p in r.points)
    parts = []
    bcoh = by.get("bc-oh")
    if bcoh is not None:
        seen = [(p.iteration, p) for p in bcoh.points if p.normalized is not None]
        parts.append("BC-OH reaches " + ", ".join(f"{p.normalized.mean:.1f}% of expert at {thousands(i)}" for i, p in seen))
        judged = [(i, p.diagnostics) for i, p in seen if p.diagnostics.read]
        if judged:
            parts.append("it is judged copycat in " + ", ".join(f"{d.copycats} of {d.read} seeds at {thousands(i)}"
                                                               for i, d in judged))
    for lab, d in diffs:
        ci = d.get(end)
        if ci is not None:
            a, b = lab.split(" − ")
            parts.append(f"at {thousands(end)} {lab} is {ci.diff:+.1f} points ({_ci(ci)}; {verdict(ci, a, b)})")
    return f"{title}: " + "; ".join(parts) + "." if parts else f"{title}: nothing to compare."


def paper_budget_section(merged: dict, figure) -> list[str]:
    """"The paper's budget with the paper's recipe": per task (`analysis.paper_budget_groups`), every method of
    `analysis.BUDGET_METHODS` at each iteration its runs were evaluated at, in % of expert with bootstrap intervals,
    its return at the end beside the supplement's Table 5 (each source's ratio to BC-OH), the differences the
    copycat question turns on at each point, and the copycat diagnostics at each point; `figure(name, alt, draw)`
    links the section's figure (`build`'s)."""
    groups = paper_budget_groups(merged)
    if not groups:
        return []
    rows = [budget_rows(m) for m in groups]
    its = sorted({p.iteration for task in rows for r in task for p in r.points})
    end = its[-1]
    p = groups[0]["protocol"]
    out = [f"### The paper's budget with the paper's recipe: the same runs at {', '.join(f'{i:,}' for i in its)} "
           "iterations", "",
           f"Protocol {FCA}, split by {p.get('split')}, recipe fca (the FCA code's network and optimiser), "
           f"{end:,} iterations with the learning rate × 0.1 at a third and two thirds of the run (the FCA code's "
           "100k and 200k of 300k). Each run's policy was also evaluated, on the same episodes and with the same "
           "diagnostics, at the iterations of `budget.eval_at` before the end, so each column is the same runs "
           "earlier in training (their learning rate not yet decayed where the point comes before 100k). % of "
           "expert: the mean over seeds with its 95% percentile bootstrap interval. The return at the end is on "
           "the paper's scale; the supplement's Table 5 is beside it, and since the experts differ (the paper does "
           "not publish its own), each source's ratio to its own BC-OH is the comparison that does not depend on "
           "them.", ""]
    out += figure("paper-budget.png", "The paper's budget: % of expert and the embedding ratio against iterations",
                  lambda: figures.budget_figure(rows))
    out += ["| task | method | seeds | " + " | ".join(f"% of expert at {i:,}" for i in its)
            + f" | return at {end:,} [95% CI] | × BC-OH | Table 5 | × BC-OH |",
            "|---|---|---:|" + "---:|" * (len(its) + 4)]
    for task in rows:
        title = tasks.get(task[0].env).title
        paper_bcoh = PAPER_TABLE5["bc-oh"][task[0].env]
        for r in task:
            last = r.at(end)
            ret = last.returns if last is not None else None
            seeds = len(ret.seeds) if ret is not None else 0
            ratio = _ratio_cell(task, r, [end])
            paper = "—" if r.paper is None else f"{r.paper:,.0f}"
            paper_ratio = "—" if r.paper is None else f"{r.paper / paper_bcoh:.2f}×"
            out.append(f"| {title} | {r.label} | {seeds} | " + " | ".join(_pct_cell(None if (q := r.at(i)) is None
                                                                                      else q.normalized) for i in its)
                       + " | " + ("—" if ret is None else f"{ret.mean:,.0f} [{ret.low:,.0f}, {ret.high:,.0f}]")
                       + f" | {ratio} | {paper} | {paper_ratio} |")
    out += ["", "Differences over seeds in points of % of expert at each iteration: BC-OH − BC-SO (what the history "
            "adds; the paper reads copycat from it not helping) and each other method − BC-OH (does it beat BC-OH?), with "
            "95% bootstrap intervals (each arm's seeds resampled independently), bold where the interval excludes "
            "0.", "", "| task | difference | " + " | ".join(f"at {i:,}" for i in its) + " |",
            "|---|---|" + "---:|" * len(its)]
    diffs = [budget_differences(task) for task in rows]
    state = any(p.diagnostics.state is not None for task in rows for r in task for p in r.points)
    for task, d in zip(rows, diffs):
        out += [f"| {tasks.get(task[0].env).title} | {lab} | " + " | ".join(_diff_cell(ci.get(i)) for i in its) + " |"
                for lab, ci in d]
    out += ["", "The copycat diagnostics at each iteration (medians over seeds, " + " → ".join(thousands(i) for i in its)
            + "): the embedding ratio (the embedding probe's held-out error on a_{t−1} ÷ the same probe's from a_t "
            "alone: below 1 the embedding carries the previous action beyond what the current one gives), the "
            "predictability ratio (a ψ-architecture predictor's held-out error on the policy's own rollout actions ÷ "
            "the same on the expert's: below 1 the policy's actions are more predictable from its previous ones "
            "than the expert's), and the seeds judged copycat out of those read"
            + ("; and beside them, where recorded, the embedding probe's error ÷ the same probe's from the true "
               "state at t (below 1: the embedding carries a_{t−1} beyond what the state itself tells)" if state
               else "") + ".", "",
            "| task | method | embedding ratio | predictability ratio | copycat |" + (" embedding ÷ state |" if state else ""),
            "|---|---|---:|---:|---:|" + ("---:|" if state else "")]
    for task in rows:
        title = tasks.get(task[0].env).title
        out += [f"| {title} | {r.label} | {_ratios(r, its, 'embedding')} | {_ratios(r, its, 'predictability')} | "
                + " → ".join("—" if (q := r.at(i)) is None or not q.diagnostics.read
                             else f"{q.diagnostics.copycats}/{q.diagnostics.read}" for i in its) + " |"
                + (f" {_ratios(r, its, 'state')} |" if state else "") for r in task]
    sources = [src for m in groups for src in m["sources"]]
    out += ["", thresholds_line(diagnostics_thresholds(sources)), ""]
    out += [f"- {_budget_reading(task, d)}" for task, d in zip(rows, diffs)] + [""]
    return out


def _point_diag(q: MapPoint, field: str) -> str:
    return "—" if q.diagnostics is None else _ratio(getattr(q.diagnostics, field), with_range=False)


def extended_map_section(merged: dict, figure) -> list[str]:
    """"Where copycat appears: the map, extended": every fca-family state group (`analysis.extended_map`), per
    setting (recipe, split), frame skip, training-set size, run length and evaluation point, the three map methods
    in % of expert and BC-OH − BC-SO with its interval; then, for the cells whose files record them, BC-OH's
    copycat diagnostics in a table of their own (so files without diagnostics report as before, and adding them
    only adds lines). Nothing where the map has no axis beyond the copycat map's (one setting, one budget, no
    diagnostics); `figure` as in `paper_budget_section`."""
    points = extended_map(merged)
    diagnosed = [q for q in points if q.diagnostics is not None and (q.diagnostics.read or q.diagnostics.absent)]
    if len({q.setting for q in points}) < 2 and len({q.run for q in points}) < 2 and not diagnosed:
        return []
    names = [lab for lab, _, _ in MAP_METHODS]
    out = ["### Where copycat appears: the map, extended", "",
           f"Every result of the paper's protocol ({FCA}) and its variants, on four axes: the recipe (`mlp`, the "
           "project's first, whose map cells split the demonstrations by whole episodes; `fca`, the FCA code's, "
           "split by rows as its code does; a history other than the protocol's 2 observations is named there), the "
           "frame skip, the training-set size, and the budget (the run's length, and for runs evaluated during "
           "training each iteration they were evaluated at). Per cell, BC-SO, "
           "BC-OH and Ours (step THR 10% W 5) in % of expert (mean ± std over seeds), and BC-OH − BC-SO in points "
           "with its 95% bootstrap interval (bold where it excludes 0): copycat was inferred from a small or "
           "negative BC-OH − BC-SO.", ""]
    out += figure("copycat-map-extended.png", "Where copycat appears: the history's benefit and BC-OH's "
                  "diagnostics along each axis", lambda: figures.extended_map_figure(points))
    lead = "| task | recipe, split | frame skip | training transitions | run | at | "  # and a history not the protocol's
    out += [lead + " | ".join(names) + " | BC-OH − BC-SO [95% CI] |", "|---|---|---:|---:|---:|---:|"
            + "---:|" * (len(names) + 1)]

    def cells(q: MapPoint) -> str:
        history = ("" if q.observations is None else f", history {q.observations}") + (
            "" if q.expert is None else f", expert {q.expert}")
        return (f"| {tasks.get(q.env).title} | {q.recipe}, {q.split}{history} | {q.frame_skip} | {q.train_transitions:,} | "
                f"{thousands(q.run)} | {thousands(q.iteration)} | ")

    out += [cells(q) + " | ".join(map(_map_cell, q.cells)) + f" | {_diff_cell(q.history)} |" for q in points]
    out += [""]
    if diagnosed:
        state = any(q.diagnostics.state is not None for q in diagnosed)
        out += ["BC-OH's copycat diagnostics in the cells whose files record them, which test that inference: "
                "the median embedding ratio and predictability ratio over seeds (below 1: the embedding carries "
                "a_{t−1} beyond what a_t gives; the policy's actions are more predictable than the expert's), and "
                "the seeds judged copycat"
                + ("; where recorded, the embedding probe's error ÷ the same probe's from the true state at t "
                   "(below 1: beyond what the state itself tells) and the velocity probe's 1 − R² (near 0: the "
                   "embedding holds the velocity the history is for)" if state else "") + ".", "",
                lead + "BC-OH − BC-SO | embedding ratio | predictability ratio | copycat |"
                + (" embedding ÷ state | velocity 1 − R² |" if state else ""),
                "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|" + ("---:|---:|" if state else "")]
        out += [cells(q) + ("—" if q.history is None else f"{q.history.diff:+.1f}") + f" | "
                f"{_point_diag(q, 'embedding')} | {_point_diag(q, 'predictability')} | "
                + ("—" if not q.diagnostics.read else f"{q.diagnostics.copycats}/{q.diagnostics.read}") + " |"
                + (f" {_point_diag(q, 'state')} | {_point_diag(q, 'velocity')} |" if state else "")
                for q in diagnosed]
        sources = [src for key, m in ordered(merged) for src in m["sources"]]
        judged = [q for q in diagnosed if q.diagnostics.read]
        copycat = [q for q in judged if q.diagnostics.copycats]
        out += ["", thresholds_line(diagnostics_thresholds(sources)), ""]
        if judged:
            out += [f"Of the {len(judged)} cells whose BC-OH policies were diagnosed, "
                    + (f"{len(copycat)} {'has' if len(copycat) == 1 else 'have'} a seed judged copycat: " + "; ".join(
                        f"{tasks.get(q.env).title} {q.setting}, frame skip {q.frame_skip}, "
                        f"{q.train_transitions:,} transitions, at {thousands(q.iteration)} of {thousands(q.run)} "
                        f"({q.diagnostics.copycats}/{q.diagnostics.read})" for q in copycat)
                       if copycat else "none has a seed judged copycat") + ".", ""]
    return out
