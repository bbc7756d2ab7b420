"""The sensitivity study (the supplement's §4), and the training curves and weights: how concentrated a batch's
weights are on the raw APE and on the APE ÷ its mean, with what each group trained on."""

from __future__ import annotations

import numpy as np

from experiments.report import figures
from experiments.report.analysis import (APE_SCALES, BRAX, Key, Merged, WeightShares, ordered, percent, sensitivity,
                                         weight_shares)
from experiments.report.paper import PAPER_SENSITIVITY_TAU, PAPER_SENSITIVITY_W, PAPER_STEP
from experiments.report.sections.common import Context, Section, norm_cell, return_cell, table


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
    rows = [[f"softmax τ {t:g}", return_cell(r).split(" (")[0], norm_cell(r),
             f"Walker2d {PAPER_SENSITIVITY_TAU[t][0]} ± {PAPER_SENSITIVITY_TAU[t][1]}"] for t, r in tau]
    rows += [[f"step THR {percent(PAPER_STEP['thr'])}, W {x:g}", return_cell(r).split(" (")[0], norm_cell(r),
              f"driving {PAPER_SENSITIVITY_W[x]}% success"] for x, r in w]
    return table(["setting", "ours: Walker2d return", "ours: % of expert", "paper"], rows)


def _top(y: np.ndarray | None, fraction: float = 0.0) -> str:
    """The share of a batch's weight its heaviest sample (`fraction` 0) or heaviest `fraction` carry, in %."""
    if y is None:
        return "—"
    return f"{100 * y[max(1, round(fraction * len(y))) - 1]:.0f}%"


def weights_table(shares: list[WeightShares]) -> str:
    """The heaviest sample's and the heaviest 10%'s share of a batch's weight, per group and setting, with the
    weights computed on each APE scale (`analysis.APE_SCALES`)."""
    raw, by_mean = APE_SCALES["none"], APE_SCALES["mean"]
    return table(["task", "weighting", f"{raw}: heaviest sample's share", "heaviest 10%'s",
                  f"{by_mean}: heaviest sample's share", "heaviest 10%'s"],
                 [[w.title, lab, _top(y_raw), _top(y_raw, 0.1), _top(y_mean), _top(y_mean, 0.1)]
                  for w in shares for lab, y_raw, y_mean in w.series], 2)


def trained_table(shares: list[WeightShares]) -> str:
    """Per group, the APE its softmax runs trained on and its raw training APE's mean (recorded or estimated from
    the recorded quantiles)."""
    return table(["task", "softmax runs trained on", "raw training APE's mean"],
                 [[w.title, f"`normalization: {w.trained}`, the {APE_SCALES[w.trained]}",
                   "—" if w.mean_ape <= 0 else f"{w.mean_ape:.3g}" + ("" if w.mean_recorded else " (estimated)")]
                  for w in shares], 2)


# -- the sections ------------------------------------------------------------------------------------------------

def sensitivity_section(ctx: Context) -> list[Section]:
    """"Sensitivity": our Walker2d τ and W next to the supplement's §4 (`sensitivity_table`), or nothing."""
    found = sensitivity_table(ctx.merged)
    if not found:
        return []
    return [Section("Sensitivity (the supplement's §4)",
                    f"Walker2d (states, protocol {SENSITIVITY.protocol}), return mean ± sd over seeds; the paper's W "
                    "study was on CARLA driving.", [found])]


def curves_and_weights_section(ctx: Context) -> list[Section]:
    """"Training curves and weights": the curves figure, the weights figure, the weights table and which APE scale
    each group trained on; nothing where no file records curves or APE quantiles."""
    shares = weight_shares(ctx.merged)
    body = []
    for f in figures.families(m for _, m in ordered(ctx.merged)):
        body += ctx.figure(f"curves-{f.name}.png", f"Training curves: {f.heading}",
                           lambda f=f: figures.curves_figure(f))
    for trained, (suffix, words) in figures.TRAINED_ON.items():
        body += ctx.figure(f"weights-{suffix}.png",
                           f"Weight concentration within a batch, groups trained on {words}",
                           lambda trained=trained: figures.weights_figure(shares, trained))
    if shares:
        body += [weights_table(shares), trained_table(shares)]
    if not body:
        return []
    return [Section("Training curves and weights",
                    "Batches of 128 drawn from each group's training APE and weighted as the sweep does; the share of "
                    "a batch's weight its heaviest samples carry, on both APE scales.", body)]
