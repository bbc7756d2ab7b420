"""The sensitivity study (the supplement's §4), and the training curves and weights: how concentrated a batch's
weights are on the raw APE and on the APE ÷ its mean, with what each group trained on."""

from __future__ import annotations

import numpy as np

from experiments.report import figures
from experiments.report.analysis import APE_SCALES, BRAX, Key, Merged, WeightShares, percent, sensitivity, weight_shares
from experiments.report.paper import PAPER_SENSITIVITY_TAU, PAPER_SENSITIVITY_W, PAPER_STEP
from experiments.report.sections.common import Context, Section, norm_cell, return_cell


SENSITIVITY = Key("walker2d", "pos", BRAX)  # the group the sensitivity study ran in (its committed file is brax's)


def sensitivity_table(merged: Merged) -> str | None:
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
        lines.append(f"| softmax τ {t:g} | {return_cell(r).split(' (')[0]} | {norm_cell(r)} | {paper} |")
    for x, r in w:
        lines.append(f"| step THR {percent(PAPER_STEP['thr'])}, W {x:g} | {return_cell(r).split(' (')[0]} | "
                     f"{norm_cell(r)} | "
                     f"driving {PAPER_SENSITIVITY_W[x]}% success |")
    for name, group in (("τ", tau), ("W", w)):
        got = [r for _, r in group if r is not None]
        if len(got) == len(group):
            spread = max(r["return_mean"] for r in got) - min(r["return_mean"] for r in got)
            std = max(r["return_std"] for r in got)
            word = "within" if spread <= std else "beyond"
            lines.append(f"\nOver {name}: the means span {spread:,.0f}, {word} the largest std over seeds "
                         f"({std:,.0f}).")
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


# -- the sections ------------------------------------------------------------------------------------------------

def sensitivity_section(ctx: Context) -> list[Section]:
    """"Sensitivity": our Walker2d τ and W next to the supplement's §4 (`sensitivity_table`), or nothing."""
    table = sensitivity_table(ctx.merged)
    if not table:
        return []
    return [Section("Sensitivity (the supplement's §4)",
                    f"Walker2d (states, protocol {SENSITIVITY.protocol}), softmax τ and the step weight W at THR "
                    f"{percent(PAPER_STEP['thr'])}, "
                    "next to the paper's numbers (its W study was on CARLA driving, so only the pattern compares).",
                    [table])]


def curves_and_weights_section(ctx: Context) -> list[Section]:
    """"Training curves and weights": the curves figure, the weights figure, the weights table and which APE scale
    each group trained on; nothing where no file records curves or APE quantiles."""
    shares = weight_shares(ctx.merged)
    curves = ctx.figure("curves.png", "Training curves", lambda: figures.curves_figure(ctx.merged))
    weights = ctx.figure("weights.png", "Weight concentration within a batch", lambda: figures.weights_figure(shares))
    body = curves.lines + weights.lines
    if shares:
        body += [weights_table(shares)] + [f"- {trained_on(w)}" for w in shares] + [""]
    if not body:
        return []
    return [Section(
        "Training curves and weights",
        "From the results files that record them (runs since the training curve and the APE quantiles "
        "were added to `results.json`). Weights: batches of 128 drawn from each group's training APE "
        "distribution and weighted as the sweep does, `B·softmax(APE/τ)` or the step function; each curve "
        "is the share of a batch's total weight its k heaviest samples carry (uniform weights: the "
        "diagonal). A curve near 1 at k = 1 is a batch whose loss is one sample's. The softmax acts on "
        f"whichever APE a run trained on: the {APE_SCALES['none']}, or the {APE_SCALES['mean']}, which "
        "multiplies it by one over its mean (usually far more than 1) and so makes a τ ≤ 1 put nearly all "
        "of a batch's weight on one sample. Both are shown for every group, computed from its recorded "
        "quantiles; the step and uniform weights depend only on ranks and are the same on both.",
        body, {**curves.figures, **weights.figures})]
