"""Sample weights from action prediction errors (APE): the paper's step and softmax functions.

Public, pure and jit-able, as the paper defines them (`docs/concepts/weighting.md`):

- `step(ape, thr, w)` — dataset level: the ⌊thr·N⌋ samples with the largest APE
  get weight `w`, all others 1 (ties broken by index: the lower index ranks higher);
- `softmax(ape_batch, tau)` — minibatch level: `B · softmax(ape_batch / tau)`, so
  a batch's weights average to 1;
- `uniform(ape)` — all ones (BC-OH).

For one compiled program over the whole grid, every configuration is a
`Weighting` pytree of scalars (`kind`, `thr`, `w`, `tau`, `source`) and weights
are computed in two stages with one calling convention: `dataset_weights(scores,
hp)` once before training (the step function's ranking over the whole training
set), then `batch_weights(scores, static, idx, hp)` for each minibatch.
Stacking `Weighting`s along a leading axis and `vmap`ping over it covers
uniform, step and softmax configurations alike.

`scores` is a table `[S, N]` of per-sample scores and `source` picks its row:
row 0 is the APE; the weighting baselines add theirs (BOCPD's changepoint
probability ranked by the same step function, or ActFreq's and k-means' weights
used as they are with the `given` kind), so they join the same program.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from ape_jax.ape import NORMALIZATIONS

UNIFORM, STEP, SOFTMAX, GIVEN = 0, 1, 2, 3
KINDS = {"uniform": UNIFORM, "step": STEP, "softmax": SOFTMAX, "given": GIVEN}
# The paper's grids (Sec. 5, "Implementation details"; its code's `--thr`/`--weight` and `--temperature` sweeps)
STEP_GRID = tuple((thr, w) for thr in (0.1, 0.2) for w in (3.0, 5.0, 10.0))
SOFTMAX_GRID = (0.1, 0.2, 0.5, 1.0, 5.0, 10.0)


@dataclasses.dataclass(frozen=True)
class StepKnobs:
    """A step weighting's own settings (`ours-step`'s, and a step plugin's without a fixed grid:
    `--set ours-step.grid=0.1:5,0.2:3`, or `experiments.sweep --step-grid` for every step weighting at once).

    Attributes:
      grid: the (THR, W) settings it runs at: THR in (0, 1), W finite and >= 1; default the paper's `STEP_GRID`.
    """

    grid: tuple[tuple[float, float], ...] = STEP_GRID

    def __post_init__(self):
        for thr, w in self.grid:
            if not (0.0 < thr < 1.0 and 1.0 <= w < math.inf):
                raise ValueError(f"grid: THR must be in (0, 1) and W a finite number >= 1, got {thr:g}:{w:g}")
        if len(set(self.grid)) != len(self.grid):
            raise ValueError(f"grid lists a setting twice: {self.grid!r}")


@dataclasses.dataclass(frozen=True)
class SoftmaxKnobs:
    """A softmax weighting's own settings (`ours-softmax`'s: `--set ours-softmax.taus=0.2`, or
    `experiments.sweep --softmax-grid` for every softmax weighting at once).

    Attributes:
      taus: the temperatures τ it runs at, each finite and > 0; default the paper's `SOFTMAX_GRID`; empty: none
        (the image presets leave the softmax weighting out).
      ape_normalization: the APE the softmax reads: `"none"`, the raw APE, as the official code's
        `softmax(APE / τ)` (`network/loss.py`), so the paper's τ grid means what it meant there; `"mean"`, divided
        by its training-set mean (τ then means τ · mean APE). A step weighting ranks the APE, so no scale changes
        it; the sweep fits one APE, so its softmax weightings take one normalisation
        (`Settings.ape_normalization`).
    """

    taus: tuple[float, ...] = SOFTMAX_GRID
    ape_normalization: str = "none"

    def __post_init__(self):
        if self.ape_normalization not in NORMALIZATIONS:
            raise ValueError(f"ape_normalization must be one of {', '.join(NORMALIZATIONS)}, got "
                             f"{self.ape_normalization!r}")
        if not all(0.0 < v < math.inf for v in self.taus):
            raise ValueError(f"taus: every value must be a finite number > 0, got {self.taus!r}")
        if len(set(self.taus)) != len(self.taus):
            raise ValueError(f"taus lists a setting twice: {self.taus!r}")


def _count(thr: jax.Array, n: int) -> jax.Array:
    # ⌊thr·N⌋ with a tolerance of a few float32 ulps: thr = 0.7 is stored as
    # 0.69999999, and ⌊0.69999999·10⌋ would upweight 6 samples instead of 7.
    return jnp.floor(thr * n + n * 2.0**-21).astype(jnp.int32)


def step(ape: jax.Array, thr: jax.Array | float, w: jax.Array | float) -> jax.Array:
    """Dataset-level step weights.

    Args:
      ape: per-sample APE over the whole training set, `[N] float32`.
      thr: fraction of samples upweighted, in (0, 1) (traced or static).
      w: their weight, >= 1.

    Returns:
      `[N] float32`: `w` for the ⌊thr·N⌋ largest APE values (ties: lower index
      first), 1 elsewhere.
    """
    ape = jnp.asarray(ape)
    if ape.ndim != 1:
        raise ValueError(f"step: ape must be [N], got shape {ape.shape}")
    n = ape.shape[0]
    order = jnp.argsort(-ape, stable=True)             # largest first, equal values by index
    rank = jnp.zeros(n, jnp.int32).at[order].set(jnp.arange(n, dtype=jnp.int32))
    return jnp.where(rank < _count(jnp.asarray(thr, jnp.float32), n), jnp.asarray(w, jnp.float32), 1.0)


def softmax(ape_batch: jax.Array, tau: jax.Array | float) -> jax.Array:
    """Minibatch-level softmax weights `B · softmax(ape_batch / tau)`.

    Args:
      ape_batch: APE of the minibatch's samples, `[B] float32`.
      tau: temperature, > 0.

    Returns:
      `[B] float32` weights with mean 1.
    """
    ape_batch = jnp.asarray(ape_batch, jnp.float32)
    if ape_batch.ndim != 1:
        raise ValueError(f"softmax: ape_batch must be [B], got shape {ape_batch.shape}")
    return ape_batch.shape[0] * jax.nn.softmax(ape_batch / tau)


def uniform(ape: jax.Array) -> jax.Array:
    """All-ones weights of `ape`'s shape (BC-OH)."""
    return jnp.ones(jnp.shape(ape), jnp.float32)


@struct.dataclass
class Weighting:
    """One weighting configuration as traced scalars (stack them for a grid).

    `kind` is `UNIFORM`, `STEP`, `SOFTMAX` or `GIVEN` (the score row is the
    weight); the fields a kind does not use are ignored (keep them at harmless
    values such as 1). `source` is the row of the score table the kind reads
    (0: APE).
    """

    kind: jax.Array    # [] int32
    thr: jax.Array     # [] float32, STEP
    w: jax.Array       # [] float32, STEP
    tau: jax.Array     # [] float32, SOFTMAX
    source: jax.Array  # [] int32, the score row

    @classmethod
    def make(cls, kind: str, thr: float = 0.1, w: float = 1.0, tau: float = 1.0, source: int = 0) -> Weighting:
        """A configuration; raises `ValueError` for an unknown kind or invalid values."""
        if kind not in KINDS:
            raise ValueError(f"unknown weighting {kind!r}; valid: {sorted(KINDS)}")
        validate(kind, thr=thr, w=w, tau=tau)
        if source < 0:
            raise ValueError(f"weighting source must be a row index >= 0, got {source}")
        return cls(kind=jnp.int32(KINDS[kind]), thr=jnp.float32(thr), w=jnp.float32(w), tau=jnp.float32(tau),
                   source=jnp.int32(source))


def validate(kind: str, thr: float = 0.1, w: float = 1.0, tau: float = 1.0) -> None:
    """Refuses invalid hyperparameters with a one-line `ValueError`."""
    if kind == "step":
        if not 0.0 < thr < 1.0:
            raise ValueError(f"step weighting: THR must be in (0, 1), got {thr}")
        if not (w >= 1.0 and np.isfinite(w)):
            raise ValueError(f"step weighting: W must be >= 1 and finite, got {w}")
    if kind == "softmax" and not (tau > 0.0 and np.isfinite(tau)):
        raise ValueError(f"softmax weighting: tau must be > 0 and finite, got {tau}")


def stack(configs: list[Weighting]) -> Weighting:
    """The configurations stacked along a leading grid axis `[G]`."""
    return jax.tree.map(lambda *xs: jnp.stack(xs), *configs)


def _table(scores: jax.Array) -> jax.Array:
    scores = jnp.asarray(scores, jnp.float32)
    return scores[None] if scores.ndim == 1 else scores


def dataset_weights(scores: jax.Array, hp: Weighting) -> jax.Array:
    """`[N]` weights fixed before training.

    Args:
      scores: the score table `[S, N]` (or just the APE, `[N]`).
      hp: the configuration.

    Returns:
      The step function's weights of score row `hp.source` for `STEP`, the row
      itself for `GIVEN`, ones otherwise.
    """
    row = _table(scores)[hp.source]
    return jnp.where(hp.kind == STEP, step(row, hp.thr, hp.w), jnp.where(hp.kind == GIVEN, row, 1.0))


def batch_weights(scores: jax.Array, static: jax.Array, idx: jax.Array, hp: Weighting) -> jax.Array:
    """`[B]` weights of minibatch rows `idx`.

    Args:
      scores: the score table `[S, N]` (or just the APE, `[N]`).
      static: `dataset_weights(scores, hp)`, `[N]`.
      idx: the minibatch's rows, `[B] int32`.
      hp: the configuration.
    """
    tau = jnp.where(hp.kind == SOFTMAX, hp.tau, 1.0)  # keeps the unused branch finite
    weights = jnp.where(hp.kind == SOFTMAX, softmax(_table(scores)[hp.source, idx], tau), static[idx])
    return jax.lax.stop_gradient(weights)
