"""The report's figures of returns, grids, curves and weights, built from merged results with the drawing
primitives.

`grid_figure` (one group's grid search), `returns_figure` (every method's % of expert per group, one figure per
family of groups, `families`), `curves_figure` (training curves, one figure per family), `weights_figure` (how
concentrated a batch's weights are, on the raw APE and on the APE ÷ its mean, one figure per APE scale the groups
trained on) and `ranking_figure` (the later methods ranked: IQM with its interval per family of cells). Each returns
a `matplotlib.figure.Figure`, or None when there is nothing to draw. The copycat figures are in `figures.copycat`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

from experiments.report.analysis import (CEILING, STATE, Group, Merged, WeightShares, best_of, config_key,
                                         display_metric, extra_methods, hparams_suffix, in_state_family, known_methods,
                                         label,
                                         method_rows, metric_value, ordered, paper_step_row, percent, seed_values)
from experiments.report.analysis.ranking import Family as CellFamily
from experiments.report.figures.families import Family, panel_title
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
        ref = f"; BC-OH {center:.1f}" + (f" ± {std:.1f}" if math.isfinite(std) else "")
    over = f"mean ± sd over {seeds} seeds" if seeds > 1 else "1 seed: no sd"
    title = f"{m.title}: grid search, {unit} ({over}){ref}"
    return heatmap(title, panels, center, unit)


def _grid_panel(title, row_label, col_label, rows, cols, cells, prefix, marked) -> Grid:
    mean = np.array([[metric_value(c, prefix)[0] if c else np.nan for c in line] for line in cells])
    std = np.array([[metric_value(c, prefix)[1] if c else np.nan for c in line] for line in cells])
    best = np.unravel_index(np.nanargmax(mean), mean.shape)
    return Grid(title, row_label, col_label, rows, cols, mean, std, (int(best[0]), int(best[1])), marked)


def returns_groups(merged: Merged) -> list[Group]:
    """The groups the returns figures draw, in report order: all but the mujoco-state family's other frame skips and
    training-set sizes, which the copycat map draws (`copycat.copycat_map_figure`)."""
    return [m for k, m in ordered(merged) if k.protocol == STATE or not in_state_family(k.protocol)]


def returns_figure(family: Family, merged: Merged) -> Figure | None:
    """Every method's result in each group of `family` (bars: mean over seeds, error bars: sd over seeds, where two
    or more seeds give one; dots: seeds), in the unit the tables use (`analysis.display_metric`: % of expert, a
    task's rate in %, else the return), or None.

    Rows: BC-SO, BC-OH, BC-full, Ours at the paper's step setting, the best softmax, then every baseline and plugin
    that ran in the family (`analysis.extra_methods`), by the label its file records (`merged` gives them); a
    method that ran in none of the family's groups has no row.
    """
    known = known_methods(merged)
    extras = [b for b in extra_methods(merged) if b != CEILING and any(method_rows(m, b) for m in family.groups)]
    def best(name: str):
        return lambda m: best_of(method_rows(m, name))

    picks = [("BC-SO", best("bc-so")), ("BC-OH", best("bc-oh")), ("BC-full", best(CEILING)),
             (PAPER_STEP_LABEL, paper_step_row), ("Ours, best softmax", best("ours-softmax")),
             *((label(known, b, online=False), best(b)) for b in extras)]
    picks = [(name, pick) for name, pick in picks if any(pick(m) is not None for m in family.groups)]
    panels, units = [], set()
    for m in family.groups:
        prefix, unit = display_metric(m)
        rows = [pick(m) for _, pick in picks]
        if not any(rows):
            continue
        units.add(unit)
        key = "normalized" if prefix == "normalized" else "return_mean"
        notes = [f"τ {r['hparams']['tau']:g}" if name == "Ours, best softmax" and r is not None else ""
                 for (name, _), r in zip(picks, rows)]
        values = [(None, None) if r is None else metric_value(r, prefix) for r in rows]
        panels.append(Bars(panel_title(m, family), unit, [v[0] for v in values], [v[1] for v in values],
                           [seed_values(m, r, key) for r in rows], notes,
                           100.0 if unit == "% of expert" else None, "expert"))
    if not panels:
        return None
    what = next(iter(units)) if len(units) == 1 else "result (the unit under each panel)"
    return bars([name for name, _ in picks], panels,
                f"{family.heading}\n{what} per method: bar = mean over seeds, line = ± sd, dots = seeds; the best "
                "softmax chosen after the fact", columns=COLUMNS)


def curves_figure(family: Family) -> Figure | None:
    """Training curves (the weighted loss of the sampled batches, mean ± std over seeds) of BC-OH, the paper's
    step setting and the best softmax, one panel per group of `family`; None if no run of it records its curve."""
    panels = []
    for m in family.groups:
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
            panels.append(Lines(panel_title(m, family), "iteration", "weighted BC loss (window mean)", series,
                                log_y=True))
    if not panels:
        return None
    return lines(panels, f"{family.heading}\ntraining curves (mean ± std over seeds)", COLUMNS, size=(4.0, 3.0))


# How the weights figures name the APE scale a group's softmax runs trained on (`WeightShares.trained`): its file
# name's suffix (`weights-raw.png`) and its words.
TRAINED_ON = {"none": ("raw", "the raw APE"), "mean": ("by-mean", "the APE ÷ its mean")}


def weights_figure(shares: Sequence[WeightShares], trained: str) -> Figure | None:
    """The share of a batch's weight carried by its k heaviest samples, against k (`analysis.weight_shares`), for
    the groups whose softmax runs trained on `trained` (`"none"`: the raw APE, `"mean"`: the APE ÷ its mean): per
    group, each weighting's curve on the raw APE (solid) and on the APE ÷ its mean (dashed, same colour). None
    where no group trained on that scale."""
    mine = [w for w in shares if w.trained == trained]
    if not mine:
        return None
    batch = len(mine[0].series[0][1])
    k = np.arange(1, batch + 1)
    names = list(dict.fromkeys(name for w in mine for name, _, _ in w.series))   # one colour per weighting
    panels = []
    for w in mine:
        series = []
        for name, raw, by_mean in w.series:
            color = f"C{names.index(name) % 10}"
            series.append((name, k, raw, None, {"color": color}))
            if by_mean is not None:
                series.append(("", k, by_mean, None, {"color": color, "ls": "--"}))
        panels.append(Lines(w.title, f"k heaviest samples of the batch of {batch}", "share of the batch's weight",
                            series, log_x=True))
    words = TRAINED_ON.get(trained, (trained, trained))[1]
    return lines(panels, f"Groups trained on {words}: how much of a batch's weight its heaviest samples carry\n"
                         "solid: weights on the raw APE; dashed: on the APE ÷ its mean",
                 COLUMNS, shared_legend=True, size=(4.0, 3.2))


def ranking_figure(families: Sequence[CellFamily], names: Mapping[str, str]) -> Figure | None:
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
