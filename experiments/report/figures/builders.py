"""The report's figures, built from merged results (`experiments.report.analysis`) with the drawing primitives.

`grid_figure` (one group's grid search), `returns_figure` (every method's return per group), `curves_figure`
(training curves), `weights_figure` (how concentrated a batch's weights are, on the raw APE and on the APE ÷ its
mean), `copycat_map_figure` (% of expert against frame skip: where the history stops helping), `budget_figure`
(the paper's budget over training) and `extended_map_figure` (the extended map's axes). Each returns a
`matplotlib.figure.Figure`, or None when there is nothing to draw; `ranking_figure` (the later methods ranked: IQM
with its interval per family of cells).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from ape_jax import tasks
from experiments.report.analysis import (FCA, FCA_TRAIN, MAP_METHODS, BudgetRow, CopycatMap, Family, Group, MapPoint,
                                         Merged,
                                         WeightShares, best_of, config_key, display_metric, extra_methods,
                                         hparams_suffix, in_fca_family, known_methods, label, method_rows, metric_value,
                                         ordered, paper_step_row, percent, seed_values, thousands)
from experiments.report.figures.primitives import COLUMNS, DPI, Bars, Grid, Lines, bars, grid_axes, heatmap, lines
from experiments.report.paper import PAPER_STEP, PAPER_STEP_LABEL, PAPER_TAU


def grid_figure(m: Group) -> Figure | None:
    """The grid search of one group (task, observation mode, protocol) as heatmaps (step THR × W, softmax τ), or None if
    neither was run."""
    prefix, unit = display_metric(m)
    panels = []
    step = {(r["hparams"]["thr"], r["hparams"]["w"]): r for r in method_rows(m, "ours-step")
            if set(r["hparams"]) == {"thr", "w"}}
    if step:
        thrs, ws = sorted({k[0] for k in step}), sorted({k[1] for k in step})
        panels.append(_grid_panel("step weighting", "THR (top fraction of APE)", "W (weight)",
                                  [percent(t) for t in thrs], [f"{w:g}" for w in ws],
                                  [[step.get((t, w)) for w in ws] for t in thrs], prefix,
                                  next(((i, j) for i, t in enumerate(thrs) for j, w in enumerate(ws)
                                        if {"thr": t, "w": w} == PAPER_STEP), None)))
    soft = {r["hparams"]["tau"]: r for r in method_rows(m, "ours-softmax") if set(r["hparams"]) == {"tau"}}
    if soft:
        taus = sorted(soft)
        tau = PAPER_TAU.get(m.env)
        panels.append(_grid_panel("softmax weighting", "", "τ (temperature)", [""], [f"{t:g}" for t in taus],
                                  [[soft[t] for t in taus]], prefix,
                                  (0, taus.index(tau)) if tau in taus else None))
    if not panels:
        return None
    bcoh = best_of(method_rows(m, "bc-oh"))
    seeds = max(r["n_seeds"] for r in (*step.values(), *soft.values()))
    ref, center = "", None
    if bcoh is not None:
        center, std = metric_value(bcoh, prefix)
        ref = f"; BC-OH {center:.1f} ± {std:.1f}"
    title = (f"{m.title}: grid search, {unit} (mean ± sd over {seeds} seeds){ref}")
    return heatmap(title, panels, center, unit)


def _grid_panel(title, row_label, col_label, rows, cols, cells, prefix, marked) -> Grid:
    mean = np.array([[metric_value(c, prefix)[0] if c else np.nan for c in line] for line in cells])
    std = np.array([[metric_value(c, prefix)[1] if c else np.nan for c in line] for line in cells])
    best = np.unravel_index(np.nanargmax(mean), mean.shape)
    return Grid(title, row_label, col_label, rows, cols, mean, std, (int(best[0]), int(best[1])), marked)


def returns_figure(merged: Merged) -> Figure | None:
    """Every method's return per group (bars: mean, error bars: std over seeds, dots: seeds), or None.

    BC-SO, BC-OH, Ours at the paper's step setting and the best softmax, then
    every baseline and plugin that ran (`analysis.extra_methods`), by its label.
    The fca family's other frame skips are left to the copycat map
    (`copycat_map_figure`). Panels wrap into rows of `COLUMNS`.
    """
    envs = [(k, m) for k, m in ordered(merged) if k.protocol == FCA or not in_fca_family(k.protocol)]
    known = known_methods(merged)
    baselines = [b for b in extra_methods(merged) if any(method_rows(m, b) for _, m in envs)]
    labels = ["BC-SO", "BC-OH", PAPER_STEP_LABEL, "Ours, best softmax",
              *(label(known, b, online=False) for b in baselines)]
    panels = []
    for _, m in envs:
        prefix, unit = display_metric(m)
        soft = best_of(method_rows(m, "ours-softmax"))
        rows = [best_of(method_rows(m, "bc-so")), best_of(method_rows(m, "bc-oh")), paper_step_row(m), soft,
                *(best_of(method_rows(m, b)) for b in baselines)]
        if not any(rows):
            continue
        key = "normalized" if prefix == "normalized" else "return_mean"
        notes = ["" for _ in rows]
        if soft is not None:
            notes[3] = f"τ {soft['hparams']['tau']:g}"
        panels.append(Bars(
            m.title, unit, [None if r is None else metric_value(r, prefix)[0] for r in rows],
            [None if r is None else metric_value(r, prefix)[1] for r in rows], [seed_values(m, r, key) for r in rows],
            notes,
            100.0 if prefix == "normalized" else None, "expert"))
    if not panels:
        return None
    return bars(labels, panels, "Return per method: bars = mean over seeds, error bars = std, dots = seeds; "
                                "best softmax selected after the fact", columns=COLUMNS)


def curves_figure(merged: Merged) -> Figure | None:
    """Training curves (the weighted loss of the sampled batches, mean ± std over seeds) of BC-OH, the paper's
    step setting and the best softmax, one panel per group; None if no run records its curve."""
    panels = []
    for _, m in ordered(merged):
        series = []
        best_soft = best_of(method_rows(m, "ours-softmax"))
        for name, row in (("BC-OH", best_of(method_rows(m, "bc-oh"))), (PAPER_STEP_LABEL, paper_step_row(m)),
                          ("Ours, best softmax" + hparams_suffix(best_soft), best_soft)):
            runs = [r["train_curve"] for r in m.runs if row is not None and r["status"] == "ok"
                    and config_key(r) == config_key(row) and r.get("train_curve")]
            runs = [c for c in runs if None not in c and len(c) == len(runs[0])] if runs else []
            if runs:
                curve = np.asarray(runs, float)
                iters = m.sources[0].config["iterations"]
                x = (np.arange(curve.shape[1]) + 1) * iters / curve.shape[1]
                series.append((name, x, curve.mean(0), curve.std(0)))
        if series:
            panels.append(Lines(m.title, "iteration", "weighted BC loss (window mean)", series, log_y=True))
    return lines(panels, "Training curves (mean ± std over seeds)", COLUMNS) if panels else None


def weights_figure(shares: list[WeightShares]) -> Figure | None:
    """The share of a batch's weight carried by its k heaviest samples, against k (`analysis.weight_shares`): per
    group, each weighting's curve on the raw APE (solid) and on the APE ÷ its mean (dashed, same colour)."""
    if not shares:
        return None
    batch = len(shares[0].series[0][1])
    k = np.arange(1, batch + 1)
    panels = []
    for w in shares:
        series = []
        for i, (name, raw, by_mean) in enumerate(w.series):
            color = f"C{i % 10}"
            series.append((name, k, raw, None, {"color": color}))
            if by_mean is not None:
                series.append(("", k, by_mean, None, {"color": color, "ls": "--"}))
        trained = "raw APE" if w.trained == "none" else "APE ÷ its mean"
        panels.append(Lines(f"{w.title} (trained on {trained})", f"k heaviest samples of the batch of {batch}",
                            "share of the batch's total weight", series, log_x=True))
    return lines(panels, "How much of a batch's weight its heaviest samples carry: solid on the raw APE, dashed on "
                         "the APE ÷ its mean", COLUMNS)


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
                            yerr=[0.0 if math.isnan(c.std) else c.std for _, c in points], marker="o", ms=4,
                            capsize=3, lw=1.3, label=name)
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


def budget_figure(rows: Sequence[Sequence[BudgetRow]]) -> Figure | None:
    """The paper's budget (`analysis.budget_rows`, one list per task): per task, % of expert against the iteration
    each policy was evaluated at (log axis) with its 95% t-interval band, a line per method; below, BC-OH's and the
    others' median embedding ratio (the embedding probe's a_{t−1} error ÷ a_t alone's: below 1, the embedding carries
    the previous action) with its range over seeds. None when no task has two points."""
    tasks_rows = [r for r in rows if r and any(len(x.points) > 1 for x in r)]
    if not tasks_rows:
        return None
    returns, embeddings = [], []
    for task in tasks_rows:
        title = tasks.get(task[0].env).title
        series, emb = [], []
        for i, r in enumerate(task):
            style = {"color": f"C{i}", "marker": "o", "ms": 3}
            pts = [p for p in r.points if p.normalized is not None]
            if pts:
                series.append((r.label, [p.iteration for p in pts], [p.normalized.mean for p in pts],
                               ([p.normalized.low for p in pts], [p.normalized.high for p in pts]), style))
            pts = [p for p in r.points if p.diagnostics.embedding is not None]
            if pts:
                emb.append((r.label, [p.iteration for p in pts], [p.diagnostics.embedding.median for p in pts],
                            ([p.diagnostics.embedding.low for p in pts], [p.diagnostics.embedding.high for p in pts]),
                            style))
        ticks = sorted({p.iteration for r in task for p in r.points})
        returns.append(Lines(title, "iterations", "% of expert (95% t-interval band)", series, log_x=True,
                             xticks=ticks))
        if emb:
            emb.append(("", [min(p.iteration for r in task for p in r.points),
                             max(p.iteration for r in task for p in r.points)], [1.0, 1.0], None,
                        {"color": "0.5", "ls": ":"}))
            embeddings.append(Lines(title, "iterations", "embedding ratio (median, range over seeds)", emb,
                                    log_x=True, log_y=True, xticks=ticks))
    return lines(returns + embeddings, "The paper's budget and recipe: the same runs over training", len(returns))


def extended_map_figure(points: Sequence[MapPoint]) -> Figure | None:
    """The extended copycat map (`analysis.extended_map`): per task and axis with two or more points (frame skip;
    training transitions at frame skip 1; the iteration of the runs that were evaluated during training), BC-OH −
    BC-SO in points of % of expert with its 95% t-interval band, and BC-OH's median embedding and predictability
    ratios, a line per setting (recipe, split). None where no axis has two points."""
    panels = []
    for env in dict.fromkeys(q.env for q in points):
        mine = [q for q in points if q.env == env]
        final = [q for q in mine if q.iteration == q.run]
        axes = (("frame skip", "frame skip", [q for q in final if q.train_transitions == FCA_TRAIN
                                              and q.run == min_run(final)],
                 lambda q: q.frame_skip, lambda q: q.setting),
                ("training transitions (frame skip 1)", "data", [q for q in final if q.frame_skip == 1
                                                                 and q.run == min_run(final)],
                 lambda q: q.train_transitions, lambda q: q.setting),
                ("iteration evaluated at (frame skip 1, 20k transitions)", "training",
                 [q for q in mine if q.frame_skip == 1 and q.train_transitions == FCA_TRAIN],
                 lambda q: q.iteration, lambda q: f"{q.setting}, {thousands(q.run)} runs"))
        for xlabel, axis, qs, x_of, line_of in axes:
            lines_of: dict[str, list[MapPoint]] = {}
            for q in qs:
                lines_of.setdefault(line_of(q), []).append(q)
            lines_of = {k: sorted(v, key=x_of) for k, v in lines_of.items() if len({x_of(q) for q in v}) > 1}
            if not lines_of:
                continue
            title = f"{tasks.get(env).title}: {axis}"
            ticks = sorted({x_of(q) for v in lines_of.values() for q in v})
            gap, emb, pred = [], [], []
            for i, (name, qs_) in enumerate(lines_of.items()):
                style = {"color": f"C{i}", "marker": "o", "ms": 3}
                h = [q for q in qs_ if q.history is not None]
                if h:
                    gap.append((name, [x_of(q) for q in h], [q.history.diff for q in h],
                                ([q.history.low for q in h], [q.history.high for q in h]), style))
                for out, field in ((emb, "embedding"), (pred, "predictability")):
                    d = [q for q in qs_ if q.diagnostics is not None and getattr(q.diagnostics, field) is not None]
                    if d:
                        out.append((name, [x_of(q) for q in d], [getattr(q.diagnostics, field).median for q in d],
                                    None, style))
            none = "no diagnostics\n(files from before them)"
            for series in (emb, pred):
                if series:  # 1: the policy's ratio equals the reference's
                    series.append(("", [ticks[0], ticks[-1]], [1.0, 1.0], None, {"color": "0.5", "ls": ":"}))
            panels += [Lines(title, xlabel, "BC-OH − BC-SO (points of % of expert)", gap, log_x=True, xticks=ticks),
                       Lines(title, xlabel, "BC-OH's embedding ratio (median)", emb, log_x=True, log_y=bool(emb),
                             xticks=ticks, empty=none),
                       Lines(title, xlabel, "BC-OH's predictability ratio (median)", pred, log_x=True,
                             log_y=bool(pred), xticks=ticks, empty=none)]
    if not panels:
        return None
    return lines(panels, "Where copycat appears: the history's benefit and BC-OH's diagnostics along each axis", 3)


def min_run(points: Sequence[MapPoint]) -> int:
    """The shortest run length among `points` (the map's frame-skip and data axes compare runs of one length)."""
    return min((q.run for q in points), default=0)


def ranking_figure(families: Sequence[Family], names: dict[str, str]) -> Figure | None:
    """Per family of cells (`analysis.ranking`), each method's IQM of % of expert (dot) with its stratified bootstrap
    95% interval (line), best first, BC-OH's IQM dashed; None without a family."""
    if not families:
        return None
    n = max(len(f.ranked) for f in families)
    fig = Figure(figsize=(4.4 * len(families) + 1.2, 0.36 * n + 1.4), dpi=DPI, layout="constrained")
    for ax, f in zip(grid_axes(fig, len(families), None), families):
        y = np.arange(len(f.ranked))
        for i, r in enumerate(f.ranked):
            ax.plot([r.iqm.low, r.iqm.high], [i, i], color="#3182bd", lw=2.5, solid_capstyle="butt")
            ax.plot(r.iqm.value, i, "o", color="#08306b", ms=4)
            if r.method == "bc-oh":
                ax.axvline(r.iqm.value, color="0.4", ls="--", lw=1)
        ax.set_yticks(y, labels=[names[r.method] for r in f.ranked])
        ax.set_ylim(len(f.ranked) - 0.5, -0.5)
        name = {"copycat": "where copying is expected", "default": "the default tasks"}.get(f.name, f.name)
        ax.set_title(f"{name}: {len(f.cells)} cell" + ("s" if len(f.cells) > 1 else ""), fontsize=10)
        ax.set_xlabel("IQM, % of expert (95% CI)", fontsize=9)
        ax.grid(axis="x", color="0.9")
        ax.tick_params(labelsize=8)
    fig.suptitle("The later methods ranked with the paper's (dashed: BC-OH)", fontsize=10)
    return fig
