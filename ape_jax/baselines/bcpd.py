"""Bayesian online changepoint detection (Adams & MacKay 2007) on the expert's actions.

The baseline scores every sample by how likely the expert's action sequence
changes regime there, and ranks samples by that score exactly as the paper's
step function ranks APE.

Model, per episode, on the expert's actions `x_1, x_2, ...` (`[A]` each):

- the sequence is cut into segments; before every step a new segment starts
  with constant hazard `H`;
- within a segment the actions are i.i.d. `N(μ, σ²)` per dimension, with the
  segment mean drawn from the conjugate prior `μ ~ N(0, σ₀²)`; dimensions are
  independent, so a multivariate predictive is the product of the per-dimension
  Gaussian predictives (the noise variance is known, so no Student-t), taken
  as a sum of their logs.

Let `s_t ∈ {1, 2, ...}` be the length of the segment that contains `x_t`,
counting `x_t` itself. The filter keeps `P(s_t | x_{1:t})`:

    P(s_t = 1,     x_{1:t}) = H · P(x_{1:t-1}) · π₀(x_t)
    P(s_t = s + 1, x_{1:t}) = (1 − H) · P(s_{t-1} = s, x_{1:t-1}) · π(x_t | x_{t-s..t-1})

with `π₀` the prior predictive `N(0, σ₀² + σ²)` and `π(· | last s actions)` the
posterior predictive of a segment that has seen them. The **score** of sample
`t` is `P(s_t = 1 | x_{1:t})`: the posterior probability, after seeing `x_t`,
that `x_t` is the first action of a new segment, i.e. that the expert changed
regime between `t − 1` and `t`. (In Adams & MacKay's own indexing the run
length `r_t` drops to 0 *before* the observation that opens the new segment, so
their `P(r_t = 0 | x_{1:t})` is exactly `H` at every step; our score equals
their `P(r_t = 1 | x_{1:t}) / (1 − H)`, hence `P(r_t ≤ 1 | x_{1:t}) = H +
(1 − H) · score`, and ranks samples the same way.)

Our reading where the paper leaves details open (all arguments of
`changepoint_prob`):

- actions are standardised per dimension over the given dataset first (zero
  mean, unit variance; a constant dimension is only centred), so one set of
  defaults serves every environment;
- prior `μ ~ N(0, 1)` on that scale (`prior_var = 1`): segment means spread
  like the data;
- observation noise `σ² = 0.1` (`noise_var`): a segment's actions scatter about
  their mean with about a third of the dataset's standard deviation, i.e. a
  constant-mean segment explains ~90% of an action's variance; a jump of one
  dataset standard deviation is then ~2 predictive standard deviations per
  dimension and is flagged, small within-segment jitter is not;
- hazard `H = 1/100`: a priori segments last 100 steps on average;
- run lengths are truncated at `max_run = 256`: the probability of segments
  longer than `max_run` is merged into the last bin, whose predictive uses the
  segment's last `max_run` actions;
- episodes are independent: at an episode's first step (`t == 0`) the filter
  restarts with a segment that begins there, and that step's score is 0 — there
  is no earlier action to change from (APE is likewise near zero there), so
  episode boundaries are never flagged.

The filter is one `lax.scan` over the flat dataset (episodes contiguous), so it
is jit-able and runs the whole training set at once:

    score = bcpd.changepoint_prob(train.action, train.t)      # [N] float32, in [0, 1]
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import methods

HAZARD = 1.0 / 100.0
PRIOR_VAR = 1.0
NOISE_VAR = 0.1
MAX_RUN = 256


def changepoint_prob(actions: jax.Array, t: jax.Array, hazard: float = HAZARD, prior_var: float = PRIOR_VAR,
                     noise_var: float = NOISE_VAR, max_run: int = MAX_RUN) -> jax.Array:
    """Per-sample posterior probability that the expert's actions change regime at that step.

    Args:
      actions: expert actions, `[N, A] float32`, episodes contiguous.
      t: time index within the episode, `[N] int32` (0 at each episode start).
      hazard: prior probability `H` of a new segment at each step, in (0, 1).
      prior_var: variance `σ₀²` of the prior on a segment's mean, > 0
        (standardised scale).
      noise_var: observation noise variance `σ²` within a segment, > 0
        (standardised scale).
      max_run: run-length bins kept (static), >= 2; longer segments share the last.

    Returns:
      `[N] float32` in [0, 1]: `P(s_t = 1 | x_{1:t})` within each episode, 0 at
      every episode's first step.
    """
    actions = jnp.asarray(actions, jnp.float32)
    t = jnp.asarray(t)
    if actions.ndim != 2:
        raise ValueError(f"changepoint_prob: actions must be [N, A], got shape {actions.shape}")
    if t.shape != actions.shape[:1]:
        raise ValueError(f"changepoint_prob: t must be [N] = {actions.shape[:1]}, got shape {t.shape}")
    if not (isinstance(max_run, (int, np.integer)) and max_run >= 2):
        raise ValueError(f"changepoint_prob: max_run must be an int >= 2, got {max_run!r}")
    _check("hazard", hazard, upper=1.0)
    _check("prior_var", prior_var)
    _check("noise_var", noise_var)
    return _scores(actions, t, jnp.float32(hazard), jnp.float32(prior_var), jnp.float32(noise_var), int(max_run))


def _check(name: str, value, upper: float = np.inf) -> None:
    # Traced values (inside a caller's jit or vmap) cannot be checked here.
    if isinstance(value, (int, float, np.number)) and not 0.0 < value < upper:
        bound = "> 0" if upper == np.inf else f"in (0, {upper})"
        raise ValueError(f"changepoint_prob: {name} must be {bound}, got {value}")


def _standardize(x: jax.Array) -> jax.Array:
    std = jnp.std(x, axis=0)
    return (x - jnp.mean(x, axis=0)) / jnp.where(std > 1e-6, std, 1.0)


def _log_normal(x: jax.Array, mean: jax.Array, var: jax.Array) -> jax.Array:
    """Log density of independent Gaussians, summed over the last (action) axis."""
    return -0.5 * jnp.sum(jnp.log(2.0 * jnp.pi * var) + (x - mean) ** 2 / var, axis=-1)


@functools.partial(jax.jit, static_argnames="max_run")
def _scores(actions, t, hazard, prior_var, noise_var, max_run):
    x = _standardize(actions)
    start = (t == 0).at[0].set(True)               # the first row opens an episode whatever its t
    length = jnp.arange(1, max_run + 1, dtype=jnp.float32)  # segment length held by each bin
    precision = 1.0 / prior_var + length / noise_var        # posterior precision of μ, [R]
    grow_var = (1.0 / precision + noise_var)[:, None]       # posterior predictive variance, [R, 1]
    log_new, log_grow = jnp.log(hazard), jnp.log1p(-hazard)
    fresh = jnp.full(max_run, -jnp.inf).at[0].set(0.0)     # a segment opened by this very step

    def step(carry, inp):
        log_p, sums = carry                        # log P(s_{t-1} | x_{1:t-1}) [R]; sums of each bin's actions [R, A]
        x_t, is_start = inp
        mean = sums / noise_var / precision[:, None]
        grow = log_p + log_grow + _log_normal(x_t, mean, grow_var)
        new = log_new + _log_normal(x_t, 0.0, prior_var + noise_var)
        # Bins shift up by one; the longest two merge (the truncation).
        log_q = jnp.concatenate([new[None], grow[:-2], jnp.logaddexp(grow[-2], grow[-1])[None]])
        log_q = jnp.where(is_start, fresh, log_q - jax.nn.logsumexp(log_q))
        # Bin j now holds the last j+1 actions; after a reset the other bins hold
        # stale sums, but they carry no probability until they have been refilled.
        sums = jnp.concatenate([jnp.zeros_like(sums[:1]), sums[:-1]]) + x_t
        score = jnp.where(is_start, 0.0, jnp.exp(log_q[0]))
        return (log_q, sums), score

    init = (fresh, jnp.zeros((max_run, x.shape[1]), jnp.float32))
    _, score = jax.lax.scan(step, init, (x, start))
    return score


def _score(key, actions, t):
    return jnp.asarray(changepoint_prob(actions, t), jnp.float32)



# Ranked by the step function at the paper's setting for ours (THR 10%, W 5), like APE.
methods.weighting("bcpd", kind="step", grid=[{"thr": 0.1, "w": 5.0}], label="BCPD", role="baseline")(_score)
