"""PALR, past action leakage regularisation (Seo, Han, Sohn and Kim, NeurIPS 2023, "Regularized Behavior Cloning
for Blocking the Leakage of Past Action Information"), as a pure-functional `Learner`.

BC-OH plus a penalty on the conditional dependence between the policy's embedding `φ` (the Head's 100-unit
`embedding` layer, as FCA's adversary reads it) and the expert's previous action given its current one,
estimated by the HSCIC (Park and Muandet, 2020) on each minibatch (the paper's regularised objective):

    L = mean_i ℓ(π(o_{t−H+1..t}), a_t) + weight · HSCIC²(φ, a_{t−1} | a_t).

**The estimator** (`hscic`, PALR's eq. for the empirical HSCIC): on `n` rows with Gaussian kernel matrices
`K_X`, `K_Y`, `K_Z` (`k(u, v) = exp(−‖u − v‖² / bandwidth)`) of `X = φ`, `Y = a_{t−1}`, `Z = a_t`, the weights of
the kernel ridge regression on `Z` are the columns of `W = (K_Z + nλI)⁻¹ K_Z`, and

    HSCIC² = (1/n) Σ_i [ w_iᵀ (K_X ⊙ K_Y) w_i − 2 w_iᵀ ((K_X w_i) ⊙ (K_Y w_i)) + (w_iᵀ K_X w_i)(w_iᵀ K_Y w_i) ],

the squared HSCIC at each `z_i`, averaged over the rows: what the authors' code minimises. Only `K_X` depends on
the policy; `W` and `K_Y` are data, so no gradient runs through the regression.

Defaults as in the authors' code (`github.com/KAIST-AILab/palr`): weight 10 (`train.py`, `reg_coef_list`),
ridge λ = 1e-5 (`ridge_lambda_list`), `bandwidth` = σ² = 1 (`core/hscic.py`: `exp(−d² / σ²)` with σ² = 1
unless the median heuristic is asked for), the actions standardised by the training set's mean and standard
deviation before their kernels (`imitation/palr.py`), the embedding as it is. The weight and the bandwidth are
traced knobs (`PalrHparams`): its `weights` × `bandwidths` (`PalrKnobs`) train in one vmapped program.

Our readings:

- **The loss** is the project's BC loss (squared error summed over action dimensions), not the authors'
  tanh-Gaussian likelihood, so the weight's scale is not theirs: sweep `palr.weights` around it.
- **The previous action** at an episode's first step repeats the first action (`ape_jax.baselines._batch`), as
  FCA and the history padding do here; the authors' code puts zeros there.
- **Cost**: the estimator solves an `n × n` system and multiplies `n × n` matrices (`O(n³)`). On a 2-core CPU
  its gradient costs ~0.2× a BC-OH step at batch 64, ~1.2× at 256 and ~10× at 1024 (measured here), so it runs on
  at most `rows` rows of each minibatch (`palr.rows`, default `HSCIC_ROWS` = 256; 0: the whole batch, for
  GPUs): the rows are drawn uniformly with replacement, so the first `rows` are a uniform subsample and the
  penalty is the same estimator at a smaller `n`. Every recipe's batch up to 256 (`fca` 64, `mlp` 128) is
  estimated whole; PALR's own batch of 1,024 (recipe `mlp-b1024`) is subsampled on a CPU. Random Fourier features
  were measured first and rejected: features of `a_t` alone for the regression leave the `n × n` products (still
  ~4× a BC step at 1,024) and give a gradient at cosine 0.5–0.8 to the exact one; features of all three kernels
  (`O(n D³)`) give gradients at cosine below 0.1 with D ≤ 48.

Metrics (`[n]` float32 per `run` of `n` iterations): `"loss"` (the objective), `"unweighted_loss"` (the BC loss)
and `"hscic"` (the penalty before its weight).
"""

from __future__ import annotations

import dataclasses

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from ape_jax import methods
from ape_jax.baselines._batch import action_statistics, errors, sample_batch
from ape_jax.knobs import axis, integer, nonnegative, positive
from ape_jax.learner import (Data, Learner, LearnerConfig, gradient_step, learning_rate, make_train, policy_apply,
                             scanned_learner, trainable)

DEFAULT_WEIGHT = 10.0     # train.py: reg_coef_list = [10.]
DEFAULT_BANDWIDTH = 1.0   # core/hscic.py: sigma2 = 1. (k = exp(-d² / sigma2)) unless use_median
RIDGE = 1e-5              # train.py: ridge_lambda_list = [1e-5]
HSCIC_ROWS = 256          # rows of a minibatch the estimator reads (module docstring, "Cost"); 0: all


def gaussian_gram(x: jax.Array, bandwidth: jax.Array | float) -> jax.Array:
    """`[n, n]` kernel matrix `exp(−‖x_i − x_j‖² / bandwidth)` of rows `x [n, d]` (PALR's `gaussian_kernel`).

    Squared distances are clipped at 0 (rounding can make `‖x_i‖² + ‖x_j‖² − 2 x_i·x_j` slightly negative)."""
    sq = jnp.sum(x * x, axis=-1)
    d2 = jnp.maximum(sq[:, None] + sq[None, :] - 2.0 * x @ x.T, 0.0)
    return jnp.exp(-d2 / bandwidth)


def hscic(x: jax.Array, y: jax.Array, z: jax.Array, bandwidth: jax.Array | float,
          ridge: float = RIDGE) -> jax.Array:
    """The empirical squared HSCIC of `X` and `Y` given `Z`, averaged over the rows (the module docstring).

    Args:
      x: `[n, d_x] float32`, e.g. the policy's embeddings (the gradient flows through it).
      y: `[n, d_y] float32`, e.g. the standardised previous actions (data: no gradient).
      z: `[n, d_z] float32`, e.g. the standardised current actions (data: no gradient).
      bandwidth: the Gaussian kernel's `σ²` in `exp(−‖u − v‖² / σ²)`, > 0 (traced).
      ridge: the kernel ridge regression's λ (the system is `K_Z + nλI`).

    Returns:
      `[] float32`, >= 0 up to rounding; near 0 when `X` is independent of `Y` given `Z`.
    """
    if not (x.ndim == y.ndim == z.ndim == 2 and x.shape[0] == y.shape[0] == z.shape[0]):
        raise ValueError(f"hscic: x, y, z must be [n, d] with the same n, got {x.shape}, {y.shape}, {z.shape}")
    n = x.shape[0]
    kx = gaussian_gram(x, bandwidth)
    ky = jax.lax.stop_gradient(gaussian_gram(y, bandwidth))
    kz = jax.lax.stop_gradient(gaussian_gram(z, bandwidth))
    factor = jax.scipy.linalg.cho_factor(kz + ridge * n * jnp.eye(n, dtype=kz.dtype))
    w = jax.lax.stop_gradient(jax.scipy.linalg.cho_solve(factor, kz))  # columns w_i = (K_Z + nλI)⁻¹ k_Z(z_i)
    kx_w, ky_w = kx @ w, ky @ w
    # Σ_i w_iᵀ A w_i = Σ_ab A_ab (W Wᵀ)_ab: one n × n product of data instead of one through the gradient
    first = jnp.sum(kx * ky * (w @ w.T))
    second = jnp.sum(w * kx_w * ky_w)
    third = jnp.sum(jnp.sum(w * kx_w, axis=0) * jnp.sum(w * ky_w, axis=0))
    return (first - 2.0 * second + third) / n


@struct.dataclass
class PalrHparams:
    """Traced knobs of one PALR run (stack them along a leading axis for seeds × weights × bandwidths)."""

    weight: jax.Array     # [] float32, the HSCIC penalty's weight; 0 = BC-OH
    bandwidth: jax.Array  # [] float32, the kernels' σ² (> 0)
    lr: jax.Array         # [] float32

    @classmethod
    def make(cls, weight: float = DEFAULT_WEIGHT, bandwidth: float = DEFAULT_BANDWIDTH,
             lr: float = 2e-4) -> PalrHparams:
        """Validated hyperparameters (`ValueError`, one line, for a value out of range)."""
        nonnegative("PALR weight", weight)
        positive("PALR kernel bandwidth", bandwidth)
        positive("learning rate", lr)
        return cls(weight=jnp.float32(weight), bandwidth=jnp.float32(bandwidth), lr=jnp.float32(lr))


@struct.dataclass
class PalrState:
    """The scan carry: BC-OH's (policy variables, Adam moments, step, key) and the action statistics."""

    params: Any              # cfg.model() variables
    opt_state: Any           # on trainable(params)
    step: jax.Array          # [] int32
    key: jax.Array
    action_mean: jax.Array   # [A] float32, the training split's
    action_std: jax.Array    # [A] float32


def make_palr(cfg: LearnerConfig, rows: int = HSCIC_ROWS) -> Learner:
    """The pure functions of PALR for one static setup (the module docstring).

    Args:
      cfg: shapes, counts and the recipe (`cfg.model()` the policy, its embedding the penalised `φ`).
      rows: the estimator reads the first `min(rows, batch)` rows of each minibatch; 0: all of them.

    Returns:
      A `Learner` whose `init` and run key are `make_train(cfg)`'s: at weight 0 it trains BC-OH's policy on
      BC-OH's batches with BC-OH's loss.
    """
    if rows < 0:
        raise ValueError(f"PALR rows must be >= 0 (0: the whole batch), got {rows}")
    base = make_train(cfg)
    model, adam = cfg.model(), cfg.optimizer()
    m = cfg.batch_size if rows == 0 else min(rows, cfg.batch_size)

    def init(key: jax.Array, hp: PalrHparams, data: Data) -> PalrState:
        key_init, key_run = jax.random.split(key)  # as make_train: the same policy and batches for the same key
        params = base.init_policy(key_init, data)
        mean, std = action_statistics(data)
        return PalrState(params=params, opt_state=adam.init(trainable(params)), step=jnp.zeros((), jnp.int32),
                         key=key_run, action_mean=mean, action_std=std)

    def update(state: PalrState, hp: PalrHparams, data: Data):
        batch = sample_batch(cfg, base, data, jax.random.fold_in(state.key, state.step))
        y = (batch.previous[:m] - state.action_mean) / state.action_std
        z = (batch.action[:m] - state.action_mean) / state.action_std

        def loss_fn(variables):
            (predicted, embedding), variables = policy_apply(model, variables, batch.x, train=True,
                                                             return_embedding=True)
            bc = jnp.mean(errors(cfg, predicted, batch.action))
            penalty = hscic(embedding[:m], y, z, hp.bandwidth)
            return bc + hp.weight * penalty, ((bc, penalty), variables)

        params, opt_state, loss, (bc, penalty) = gradient_step(
            adam, state.params, state.opt_state, learning_rate(cfg, hp.lr, state.step), loss_fn)
        state = state.replace(params=params, opt_state=opt_state, step=state.step + 1)
        return state, {"loss": loss, "unweighted_loss": bc, "hscic": penalty}

    return scanned_learner(cfg, base, init, update)


@dataclasses.dataclass(frozen=True)
class PalrKnobs:
    """PALR's own settings (`--set palr.KNOB=VALUE`; the module docstring). Every pair of the two axes runs.

    Attributes:
      weights: the HSCIC penalty's weights, each finite and >= 0; default `DEFAULT_WEIGHT` (theirs).
      bandwidths: the Gaussian kernel's bandwidths σ², each finite and > 0; default `DEFAULT_BANDWIDTH` (theirs).
      rows: the rows of each minibatch the estimator reads (its cost grows as their cube); 0: the whole batch (for
        GPUs); default `HSCIC_ROWS` (ours, "Cost").
    """

    weights: tuple[float, ...] = (DEFAULT_WEIGHT,)
    bandwidths: tuple[float, ...] = (DEFAULT_BANDWIDTH,)
    rows: int = HSCIC_ROWS

    def __post_init__(self):
        axis("weights", self.weights, nonnegative)
        axis("bandwidths", self.bandwidths, positive)
        integer("rows", self.rows, 0)


def _grid(ctx) -> list[dict]:
    knobs = ctx.knobs_of("palr")
    return [{"weight": w, "bandwidth": b} for w in knobs.weights for b in knobs.bandwidths]


methods.register(methods.Method(
    "palr", "PALR", grid=_grid,
    hparams=lambda settings, lr, row: PalrHparams.make(settings["weight"], settings["bandwidth"], lr=lr),
    program="palr", learner=lambda ctx: make_palr(ctx.cfg, ctx.knobs_of("palr").rows), module=__name__,
    knobs=PalrKnobs))
