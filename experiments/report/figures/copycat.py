"""The report's copycat figures: where the history helps and what the copycat diagnostics say.

- `copycat_map_figure`: % of expert against frame skip (and training-set size) per task;
- `budget_figure`: the paper's budget over training: % of expert, then both halves of each copycat verdict (the
  embedding's ratios and the own-rollout predictability ratio), each with the verdict's threshold drawn;
- `extended_map_figure`: BC-OH − BC-SO and BC-OH's ratios along the extended map's axes, one figure per group of
  axes (`MAP_AXES`).

Each returns a `matplotlib.figure.Figure`, or None when there is nothing to draw. The thresholds drawn are the ones
the verdicts use (`ape_jax.diagnostics.THRESHOLDS`), or those the files record (`verdict_thresholds`).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping, Sequence

from matplotlib.figure import Figure

from ape_jax import tasks
from ape_jax.diagnostics import THRESHOLDS
from experiments.report.analysis import STATE_TRAIN, MAP_METHODS, BudgetRow, CopycatMap, MapPoint, thousands
from experiments.report.figures.primitives import COLUMNS, DPI, Lines, grid_axes, lines

# The extended map's axes, grouped into figures: {figure: (axis, ...)}; an axis is the part after the task in a
# panel's title.
MAP_AXES = {"map": ("frame skip", "data"), "training": ("training",)}


def verdict_thresholds(recorded: Sequence[Mapping] = ()) -> dict[str, float]:
    """The copycat verdicts' thresholds to draw: `{"embedding_ratio", "predictability_ratio", "control_ratio"}`,
    `ape_jax.diagnostics.THRESHOLDS` where the files (`analysis.diagnostics_thresholds`) record none or disagree,
    else the one set they record (over the defaults, for a field they lack)."""
    out = dataclasses.asdict(THRESHOLDS)
    if len(recorded) == 1:
        out.update({k: float(v) for k, v in recorded[0].items() if k in out and isinstance(v, (int, float))})
    return out


def copycat_map_figure(maps: list[CopycatMap]) -> Figure | None:
    """The copycat map (`analysis.copycat_map`): per task, % of expert against frame skip (log2 axis), a line per
    method (mean over seeds, error bars: std over seeds), the expert's 100% dashed, and where the task has them a
    second panel against the training transitions at frame skip 1; None without a map."""
    if not maps:
        return None
    panels = [(cm, "frame skip (simulator steps per action)", cm.rows, lambda r: r.frame_skip, 2)
              for cm in maps if len(cm.rows) >= 2]
    panels += [(cm, "training transitions, frame skip 1", cm.data_rows, lambda r: r.train_transitions, 10)
               for cm in maps if cm.data_rows]
    cols = max(1, min(COLUMNS, len(panels)))
    fig = Figure(figsize=(4.2 * cols, 3.6 * math.ceil(len(panels) / cols)), dpi=DPI, layout="constrained")
    for ax, (cm, xlabel, rows, x_of, base) in zip(grid_axes(fig, len(panels), cols), panels):
        xs = [x_of(r) for r in rows]
        for i, (name, _, _) in enumerate(MAP_METHODS):
            points = [(x_of(r), r.cells[i]) for r in rows if r.cells[i] is not None]
            if points:
                ax.errorbar([x for x, _ in points], [c.mean for _, c in points],
                            yerr=[c.std if c.std is not None and math.isfinite(c.std) else 0.0 for _, c in points],
                            marker="o", ms=4, capsize=3, lw=1.3, label=name)
        ax.axhline(100.0, color="0.4", ls="--", lw=1)
        ax.text(xs[0], 100.0, " expert", va="bottom", fontsize=7, color="0.3")
        ax.set_xscale("log", base=base)
        ax.set_xticks(xs, labels=[f"{x:,}" for x in xs])
        ax.minorticks_off()
        ax.set_title(cm.title, fontsize=10)
        ax.set_xlabel(xlabel, fontsize=9)
        ax.set_ylabel("% of expert", fontsize=9)
        ax.grid(color="0.9")
        ax.tick_params(labelsize=8)
        ax.legend(fontsize=7, frameon=False, loc="best")
    fig.suptitle("The copycat map: % of expert\n(the paper's protocol; mean ± sd over seeds)", fontsize=10)
    return fig


def _one_label(labels: Sequence[str]) -> str:
    """One legend entry for a method whose label differs per task (the paper's τ): `"Ours, softmax τ 0.2 / 0.1"`; a
    setting some tasks name after the plain label: `"FCA (TCA) / α 0.1"`."""
    labels = list(dict.fromkeys(labels))
    if len(labels) == 1:
        return labels[0]
    base = min(labels, key=len)   # a setting named in some tasks only: `"FCA (TCA) / α 0.1"`
    if all(lab == base or lab.startswith(base + ", ") for lab in labels):
        return " / ".join([base, *(lab[len(base) + 2:] for lab in labels if lab != base)])
    prefix = os.path.commonprefix(labels)
    prefix = prefix[:prefix.rfind(" ") + 1]
    return prefix + " / ".join(lab[len(prefix):] for lab in labels)


def _ratio_series(task: Sequence[BudgetRow], field: str, names: Mapping[str, str], style: Mapping[str, dict]
                  ) -> list[tuple]:
    """Per method of one task, its `field` ratio's median over seeds with the seeds' range as a band."""
    out = []
    for r in task:
        pts = [(p.iteration, s) for p in r.points if (s := getattr(p.diagnostics, field)) is not None]
        if pts:
            out.append((names[r.method], [x for x, _ in pts], [s.median for _, s in pts],
                        ([s.low for _, s in pts], [s.high for _, s in pts]), style[r.method]))
    return out


def budget_figure(rows: Sequence[Sequence[BudgetRow]], thresholds: Mapping[str, float] | None = None
                  ) -> Figure | None:
    """The paper's budget (`analysis.budget_rows`, one list per task), a column per task, against the iteration each
    policy was evaluated at (log axis), a line per method in one colour throughout:

    1. % of expert with its 95% t-interval band;
    2. the embedding ratio (the probe's a_{t−1} error from the embedding ÷ from a_t alone), with the first verdict's
       threshold (`embedding_ratio`);
    3. the control ratio (the embedding's a_{t−1} error ÷ the no-history control's, BC-SO's), with the controlled
       verdict's threshold (`control_ratio`), where the files hold it;
    4. the own-rollout predictability ratio (ψ's error on the policy's rollouts ÷ on the expert's), with both
       verdicts' threshold (`predictability_ratio`).

    Ratios are medians over seeds with the seeds' range as a band; a policy is a copycat where both halves of a
    verdict are at or below their thresholds. `thresholds` default to `verdict_thresholds()`. None when no task has
    two points.
    """
    tasks_rows = [r for r in rows if r and any(len(x.points) > 1 for x in r)]
    if not tasks_rows:
        return None
    t = verdict_thresholds() if thresholds is None else {**verdict_thresholds(), **thresholds}
    methods = list(dict.fromkeys(r.method for task in tasks_rows for r in task))   # one colour per method
    names = {m: _one_label([r.label for task in tasks_rows for r in task if r.method == m]) for m in methods}
    style = {m: {"color": f"C{i % 10}", "marker": "o", "ms": 3} for i, m in enumerate(methods)}
    below = "copycat at or below"
    measures = (("embedding", "embedding ratio (vs a_t alone)", f"first verdict: {below} {t['embedding_ratio']:g}"),
                ("control", "control ratio (vs BC-SO)", f"controlled verdict: {below} {t['control_ratio']:g}"),
                ("predictability", "predictability ratio (vs expert)",
                 f"both verdicts: {below} {t['predictability_ratio']:g}"))
    threshold = {"embedding": t["embedding_ratio"], "control": t["control_ratio"],
                 "predictability": t["predictability_ratio"]}
    panels: list[list[Lines]] = [[]]
    for task in tasks_rows:
        title = task[0].task
        ticks = sorted({p.iteration for r in task for p in r.points})
        series = []
        for r in task:
            pts = [p for p in r.points if p.normalized is not None]
            if pts:
                series.append((names[r.method], [p.iteration for p in pts], [p.normalized.mean for p in pts],
                               ([p.normalized.low for p in pts], [p.normalized.high for p in pts]), style[r.method]))
        panels[0].append(Lines(title, "iterations", "% of expert (95% t-interval)", series, log_x=True, xticks=ticks))
    for field, ylabel, ref in measures:
        row = [Lines(task[0].task, "iterations", ylabel, _ratio_series(task, field, names, style),
                     log_x=True,
                     log_y=True, xticks=sorted({p.iteration for r in task for p in r.points}),
                     empty="not recorded", refs=((threshold[field], ref),)) for task in tasks_rows]
        if any(p.series for p in row):
            panels.append(row)
    return lines([p for row in panels for p in row], "The paper's budget and recipe: the same runs over training; "
                 "ratios: median over seeds, band: their range", len(tasks_rows), shared_legend=True,
                 size=(4.2, 3.0))


def min_run(points: Sequence[MapPoint]) -> int:
    """The shortest run length among `points` (the map's frame-skip and data axes compare runs of one length)."""
    return min((q.run for q in points), default=0)


def _map_columns(points: Sequence[MapPoint], axes: Sequence[str]) -> list[tuple[str, str, list, list, list]]:
    """Per task and axis of `axes` with two or more points, `(title, xlabel, gap, embedding, predictability)`
    series, a line per setting (recipe, split)."""
    columns = []
    for env in dict.fromkeys(q.env for q in points):
        mine = [q for q in points if q.env == env]
        final = [q for q in mine if q.iteration == q.run]
        every = (("frame skip", "frame skip", [q for q in final if q.train_transitions == STATE_TRAIN
                                               and q.run == min_run(final)],
                  lambda q: q.frame_skip, lambda q: q.setting),
                 ("training transitions (frame skip 1)", "data", [q for q in final if q.frame_skip == 1
                                                                  and q.run == min_run(final)],
                  lambda q: q.train_transitions, lambda q: q.setting),
                 ("iteration evaluated at (frame skip 1, 20k transitions)", "training",
                  [q for q in mine if q.frame_skip == 1 and q.train_transitions == STATE_TRAIN],
                  lambda q: q.iteration, lambda q: f"{q.setting}, {thousands(q.run)} runs"))
        for xlabel, axis, qs, x_of, line_of in every:
            if axis not in axes:
                continue
            lines_of: dict[str, list[MapPoint]] = {}
            for q in qs:
                lines_of.setdefault(line_of(q), []).append(q)
            lines_of = {k: sorted(v, key=x_of) for k, v in lines_of.items() if len({x_of(q) for q in v}) > 1}
            if not lines_of:
                continue
            gap, emb, pred = [], [], []
            for i, (name, qs_) in enumerate(lines_of.items()):
                style = {"color": f"C{i}", "marker": "o", "ms": 3}
                h = [q for q in qs_ if q.history is not None]
                if h:
                    gap.append((name, [x_of(q) for q in h], [q.history.diff for q in h],
                                ([q.history.low for q in h], [q.history.high for q in h]), style))
                for out, field in ((emb, "embedding"), (pred, "predictability")):
                    d = [q for q in qs_ if q.diagnostics is not None and getattr(q.diagnostics, field) is not None]
                    if d:   # unlabelled: the legend of the panel above names the settings in the same colours
                        out.append(("", [x_of(q) for q in d], [getattr(q.diagnostics, field).median for q in d],
                                    None, style))
            ticks = sorted({x_of(q) for v in lines_of.values() for q in v})
            columns.append((f"{tasks.get(env).title}: {axis}", xlabel, ticks, gap, emb, pred))
    return columns


def extended_map_figure(points: Sequence[MapPoint], axes: Sequence[str] = MAP_AXES["map"],
                        thresholds: Mapping[str, float] | None = None) -> Figure | None:
    """The extended copycat map (`analysis.extended_map`) along `axes` (of "frame skip", "data", "training"): a
    column per task and axis with two or more points; rows: BC-OH − BC-SO in points of % of expert with its 95%
    t-interval band, BC-OH's median embedding ratio and its median predictability ratio, each ratio with the first
    verdict's threshold (`thresholds`, default `verdict_thresholds()`); a line per setting (recipe, split). None
    where no axis has two points."""
    columns = _map_columns(points, axes)
    if not columns:
        return None
    t = verdict_thresholds() if thresholds is None else {**verdict_thresholds(), **thresholds}
    none = "no diagnostics\n(files from before them)"
    rows = [[Lines(title, xlabel, "BC-OH − BC-SO (points of % of expert)", gap, log_x=True, xticks=ticks)
             for title, xlabel, ticks, gap, _, _ in columns],
            [Lines(title, xlabel, "BC-OH's embedding ratio (median)", emb, log_x=True, log_y=bool(emb), xticks=ticks,
                   empty=none, refs=((t["embedding_ratio"], f"first verdict: copycat at or below "
                                                            f"{t['embedding_ratio']:g}"),))
             for title, xlabel, ticks, _, emb, _ in columns],
            [Lines(title, xlabel, "BC-OH's predictability ratio (median)", pred, log_x=True, log_y=bool(pred),
                   xticks=ticks, empty=none, refs=((t["predictability_ratio"], f"copycat at or below "
                                                                              f"{t['predictability_ratio']:g}"),))
             for title, xlabel, ticks, _, _, pred in columns]]
    what = " and ".join(axes)
    return lines([p for row in rows for p in row], f"Where copycat appears along {what}: the history's benefit and "
                 "BC-OH's diagnostics", len(columns), size=(4.2, 3.4))
