"""How concentrated each weighting is within a batch, on the raw APE and on the APE divided by its mean."""

from __future__ import annotations

from typing import NamedTuple
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import weighting
from ape_jax.pipeline import results as results_lib
from experiments.report.analysis.groups import Group, Merged, ordered
from experiments.report.analysis.selection import is_number, method_rows, percent
from experiments.report.paper import PAPER_STEP


# The two APE scales a softmax weighting can act on (`config["ape"]["normalization"]`), as the report names them.
APE_SCALES = {"none": "raw APE (the official code, our default)", "mean": "APE ÷ its mean (the old default)"}


class WeightShares(NamedTuple):
    """How concentrated a group's weights are within a batch, on both APE scales (`weight_shares`).

    `trained` is the scale the group's softmax runs trained on (`"none"`: raw APE, `"mean"`: APE ÷ its training
    mean), `mean_ape` the raw training APE's mean (`ape_mean`: the recorded one where the file trained on APE ÷
    its mean, else estimated from its quantile function; `mean_recorded` says which), and `series`
    `[(label, raw, by_mean)]`, `raw[k-1]` / `by_mean[k-1]` (`[batch]` float64) the mean over batches of the share
    of the total weight the k heaviest samples carry with the weights computed on the raw APE / on the APE ÷
    `mean_ape` (`by_mean` None when the mean is 0: every sample's APE is 0).
    """

    title: str
    trained: str
    mean_ape: float
    mean_recorded: bool
    series: list[tuple[str, np.ndarray, np.ndarray | None]]


def _quantile_source(m: Group) -> results_lib.Results | None:
    """The file of group `m` whose APE quantiles the weights are drawn from: one that ran the softmax weighting
    (it trained on that file's APE), else the first that records them (with the scale they are on)."""
    def usable(ape) -> bool:  # quantiles, and what they are the quantiles of
        return (isinstance(ape, dict) and bool(ape.get("quantiles")) and ape.get("normalization") in APE_SCALES
                and (ape["normalization"] == "none" or (is_number(ape.get("scale")) and ape["scale"] > 0)))

    recorded = [src for src in m.sources if usable(src.config.get("ape"))]
    return next((src for src in recorded if any(r["method"] == "ours-softmax" for r in src.summary)),
                recorded[0] if recorded else None)


def raw_quantiles(ape: Mapping) -> np.ndarray:
    """The raw training APE's quantiles `[Q]` from a file's `config["ape"]`: its `quantiles` are of the APE it
    trained on, raw (`"none"`) or divided by its training mean, the recorded `scale` (`"mean"`)."""
    q = np.asarray(ape["quantiles"], np.float64)
    return q * float(ape["scale"]) if ape["normalization"] == "mean" else q


def quantile_mean(q: np.ndarray) -> float:
    """The mean of a distribution from its quantiles `[Q]` at evenly spaced levels 0..1: ∫₀¹ F⁻¹(p) dp, trapezoid.

    Exactly the mean of the batches `weight_shares` draws (the quantile function interpolated linearly); of a
    heavy-tailed APE it overstates the true mean, the last interval being a straight line up to the maximum
    (on the committed files' APE, by 10-40%).
    """
    q = np.asarray(q, np.float64)
    return float(((q[1:] + q[:-1]) / 2).mean())


def ape_mean(ape: Mapping) -> tuple[float, bool]:
    """The raw training APE's mean from a file's `config["ape"]`, and whether it was recorded: a file that trained on
    APE ÷ its mean records that mean as its `scale`, and sweeps since the raw-APE default record it as `raw_mean`;
    otherwise it is estimated from the quantiles (`quantile_mean`)."""
    if is_number(ape.get("raw_mean")) and ape["raw_mean"] > 0:   # recorded by sweeps since the raw-APE default
        return float(ape["raw_mean"]), True
    if ape["normalization"] == "mean" and is_number(ape.get("scale")) and ape["scale"] > 0:
        return float(ape["scale"]), True
    return quantile_mean(raw_quantiles(ape)), False


def weight_shares(merged: Merged, batch: int = 128, batches: int = 400) -> list[WeightShares]:
    """How concentrated the weights are within a batch, per group that records its APE quantiles and ran softmax.

    A training set of `batch · batches` APE values is drawn from the group's training APE distribution (its
    quantiles, `_quantile_source`; numpy seed 0) and cut into `batches` batches of `batch`, and each weighting is
    computed on it as the sweep computes it, through `ape_jax.weighting`'s two stages (`dataset_weights` over the
    training set, then `batch_weights` per batch): `batch·softmax(APE/τ)` at every τ the group ran, the paper's
    step setting (the ⌊THR·N⌋ largest APE values of the training set get W), and uniform. Each is computed once on
    the raw APE and once on the APE ÷ its mean (`ape_mean`). The step and uniform weights depend only on the APE's
    ranks, so they are the same on both scales; the softmax's are not: dividing the APE by a mean much below 1
    multiplies it by much more than 1, and a τ ≤ 1 then gives one sample nearly all of a batch's weight.

    Returns:
      `WeightShares` per group, in report order.
    """
    def share(w):  # [batches, batch] weights -> [batch] float64
        top = -np.sort(-np.asarray(w, np.float64), axis=1)
        return (np.cumsum(top, axis=1) / top.sum(1, keepdims=True)).mean(0)

    idx = jnp.arange(batches * batch).reshape(batches, batch)

    def weights(ape: np.ndarray, hp: weighting.Weighting) -> np.ndarray:  # the sweep's two stages -> [batches, batch]
        scores = jnp.asarray(ape.reshape(-1), jnp.float32)
        static = weighting.dataset_weights(scores, hp)
        return np.asarray(jax.vmap(lambda i: weighting.batch_weights(scores, static, i, hp))(idx))

    out = []
    for _, m in ordered(merged):
        src = _quantile_source(m)
        taus = sorted({r["hparams"]["tau"] for r in method_rows(m, "ours-softmax") if r["hparams"].get("tau", 0) > 0})
        if src is None or not taus:
            continue
        q = raw_quantiles(src.config["ape"])
        mean, recorded = ape_mean(src.config["ape"])
        levels = np.linspace(0, 1, len(q))
        raw = np.interp(np.random.default_rng(0).uniform(size=(batches, batch)), levels, q)
        by_mean = raw / mean if mean > 0 else None
        series = []
        for label, hp in ([(f"softmax τ {tau:g}", weighting.Weighting.make("softmax", tau=tau)) for tau in taus]
                          + [(f"step THR {percent(PAPER_STEP['thr'])} W {PAPER_STEP['w']:g}",
                              weighting.Weighting.make("step", thr=PAPER_STEP["thr"], w=PAPER_STEP["w"])),
                             ("uniform (BC-OH)", weighting.Weighting.make("uniform"))]):
            series.append((label, share(weights(raw, hp)), None if by_mean is None else share(weights(by_mean, hp))))
        out.append(WeightShares(m.title, src.config["ape"]["normalization"], mean, recorded, series))
    return out
