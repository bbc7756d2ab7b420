"""Copycat diagnostics: does a trained policy read the previous action from its history and lean on it?

`DESIGN.md`, "Copycat, diagnosed". Two measures per trained policy, from the
FCA paper (Wen et al., "Fighting Copycat Agents in Behavioral Cloning from
Observation Histories", NeurIPS 2020), and a verdict that needs both:

- **embedding probe** (its Table 3): a small MLP on the frozen policy's
  embedding predicts the expert's previous action `a_{t−1}`; its held-out MSE
  against the same probe fed `a_t` alone. A policy must encode `a_t` to act, so
  a ratio well below 1 says the embedding carries `a_{t−1}` beyond what the
  current action explains (BC-OH there: 0.38e-3 against 5.0e-3);
- **own-rollout predictability** (its Table 1): ψ's architecture
  (`ape_jax.ape`) fitted on half of the policy's own rollout episodes and
  scored on the other half, against the same for the expert's rollouts. A
  copycat repeats itself, so its actions are more predictable from its past
  actions than the expert's (BC-OH on Hopper there: 8×).

    tr, va = probe_inputs(cfg, params, train), probe_inputs(cfg, params, val)
    probe = embedding_probe(key_probe, tr.embedding, va.embedding, tr.previous_action, va.previous_action,
                            tr.action, va.action)
    pred = rollout_predictability(key_psi, traj.action, expert_traj.action,
                                  policy_valid=traj.valid, expert_valid=expert_traj.valid)
    v = verdict(probe, pred)          # v.label: "copycat" | "not copycat"; v.reasons

The probe (`fit_probe`, `probe_mse`, `probe_target`, `embedding_probe`) is
pure and jit-able (leaves are `jax.Array`s, so it vmaps over policies);
`rollout_predictability` is host code around a jitted fit, because validity
masks decide how many steps each side keeps; `verdict` is host code.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ape_jax import ape as ape_lib
from ape_jax.history import history_index
from ape_jax.learner import Data, LearnerConfig, make_train

PROBE_STEPS = 2000
PROBE_HIDDEN = 300
PROBE_LR = 1e-3
PROBE_BATCH = 256
COPYCAT, NOT_COPYCAT = "copycat", "not copycat"


# -- results ---------------------------------------------------------------------------------------------------------

class ProbeParams(NamedTuple):
    """A fitted probe: the training inputs' standardisation and the MLP's variables.

    Attributes:
      x_mean: `[D] float32`, the training inputs' mean.
      x_std: `[D] float32`, their standard deviation (1 where a column is constant).
      net: the `ape_jax.ape.ActionPredictor` variables (one hidden layer, LeakyReLU(0.2)).
    """

    x_mean: jax.Array
    x_std: jax.Array
    net: Any


class TargetProbe(NamedTuple):
    """How well a probe predicts a target on held-out rows (every field `[] float32`).

    Attributes:
      mse: the probe's held-out MSE (squared error summed over target dims, mean over rows).
      baseline: the held-out MSE of predicting the training targets' mean (the target's spread).
      ratio: `mse / baseline`, i.e. 1 − R²: near 0 the input determines the target, near 1 (or above:
        overfitting) it says nothing about it.
    """

    mse: jax.Array
    baseline: jax.Array
    ratio: jax.Array


class EmbeddingProbe(NamedTuple):
    """The embedding probe (the FCA paper's Table 3); every field `[] float32`.

    Attributes:
      prev_from_embedding: held-out MSE of the probe predicting `a_{t−1}` from the policy's embedding.
      prev_from_action: held-out MSE of the same probe predicting `a_{t−1}` from `a_t` alone.
      ratio: `prev_from_embedding / prev_from_action`: below 1, the embedding holds more about the previous
        action than the current action does.
    """

    prev_from_embedding: jax.Array
    prev_from_action: jax.Array
    ratio: jax.Array


class Predictability(NamedTuple):
    """Own-rollout predictability (the FCA paper's Table 1); host values.

    Attributes:
      policy_mse: ψ's held-out MSE on the policy's rollout actions (float).
      expert_mse: the same on the expert's rollout actions (float).
      ratio: `policy_mse / expert_mse` (float): below 1, the policy's actions are more predictable from its
        own past actions than the expert's are from theirs.
      train_rows: steps ψ was fitted on, on each side (int).
      val_rows: held-out steps on each side (int); the episodes' first steps (`t = 0`) among them are not
        scored.
    """

    policy_mse: float
    expert_mse: float
    ratio: float
    train_rows: int
    val_rows: int


class ProbeInputs(NamedTuple):
    """One split's rows for the embedding probe: those with a previous step in their episode (`t ≥ 1`).

    Attributes:
      embedding: `[N, E] float32`, the policy's embedding of each row's observation history.
      previous_action: `[N, A] float32`, the expert's `a_{t−1}`.
      action: `[N, A] float32`, the expert's `a_t`.
    """

    embedding: jax.Array
    previous_action: jax.Array
    action: jax.Array


@dataclasses.dataclass(frozen=True)
class Thresholds:
    """When a policy is called a copycat: BOTH ratios at or below their threshold. Fixed before any result.

    - `embedding_ratio = 0.5`: the embedding probe's error on `a_{t−1}` at most half the error of the same
      probe fed `a_t` alone. The FCA paper's Table 3 has BC-OH's embedding at 0.38e-3 against 5.0e-3 from
      `a_t`, a ratio of about 0.08; an embedding that holds no more about `a_{t−1}` than the action it must
      produce sits near 1. 0.5 is six times the paper's copycat (a real one is caught with room to spare)
      and a factor of two from 1 (probe noise, a few tens of percent, does not cross it).
    - `predictability_ratio = 0.5`: ψ's held-out error on the policy's own rollouts at most half of its
      error on the expert's, i.e. the policy's actions at least 2× more predictable. The paper's Table 1
      has BC-OH's actions 8× more predictable than the expert's on Hopper (ratio 0.125); a policy that
      acts like the expert sits near 1. Again 4× short of the paper's copycat, 2× from 1.

    Why both: each alone has an innocent explanation. A policy that reads the full state can carry
    `a_{t−1}` in its embedding through the dynamics (the state at t reveals the step before it) without
    leaning on it; a sluggish, underfitted policy can be smoother, so more predictable, than the expert
    without reading its past actions. A copycat does both: it encodes the previous action and its
    rollouts repeat it.
    """

    embedding_ratio: float = 0.5
    predictability_ratio: float = 0.5

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not 0.0 < value < 1.0:
                raise ValueError(f"Thresholds.{f.name} must be in (0, 1) (a ratio below 'no different from "
                                 f"the reference'), got {value}")


THRESHOLDS = Thresholds()


class Verdict(NamedTuple):
    """The copycat verdict and why.

    Attributes:
      label: `"copycat"` when both criteria held, else `"not copycat"`.
      embedding_held: the embedding probe's ratio was at or below its threshold (False when undefined).
      predictability_held: the rollout predictability ratio was at or below its threshold (False when
        undefined).
      reasons: one line per criterion: the measured ratio, the threshold, whether it held.
    """

    label: str
    embedding_held: bool
    predictability_held: bool
    reasons: tuple[str, ...]


# -- the policy's embedding ------------------------------------------------------------------------------------------

def policy_embeddings(cfg: LearnerConfig, params: Any, data: Data, idx: jax.Array,
                      chunk: int | None = None) -> jax.Array:
    """The frozen policy's embedding of rows `idx`, `[B, E] float32` (E = 100 for the project's networks).

    Each row's observation history is built as the learner builds it (`history_index`: the last
    `cfg.history` observations, the episode's first repeated before its start; `make_train(cfg)
    .policy_input`), and `cfg.model()` is applied in evaluation mode: a network with BatchNorm normalises by
    its running statistics, so a row's embedding does not depend on the other rows. The rows run in
    chunks of `chunk` (default: 256 frames for images, 4,096 rows of states) in a `lax.map`, so memory holds
    one chunk's activations. Jit-able with `cfg` static.

    Args:
      cfg: the policy's learner config (shapes, network, history length).
      params: the policy's Flax variables (`{"params": …}`, plus `{"batch_stats": …}` for `"bn-mlp"`).
      data: the split; `obs [M, *obs_shape]`, `t [M] int32`.
      idx: `[B] int32` row indices into `data.obs` (not positions in `data.rows`).
      chunk: rows per forward pass.

    Returns:
      `[B, E] float32`.
    """
    idx = jnp.asarray(idx, jnp.int32)
    if idx.ndim != 1 or idx.shape[0] < 1:
        raise ValueError(f"policy_embeddings: idx must be [B] with B >= 1, got shape {idx.shape}")
    model, learner = cfg.model(), make_train(cfg)
    b = idx.shape[0]
    chunk = max(1, min(chunk or (256 if cfg.images else 4096), b))
    rounds = -(-b // chunk)
    padded = idx[jnp.arange(rounds * chunk) % b].reshape(rounds, chunk)  # the last chunk wraps; cut off below

    def embed(rows):
        x = learner.policy_input(data.obs[history_index(data.t, rows, cfg.history)])
        return model.apply(params, x, return_embedding=True)[1]

    emb = jax.lax.map(embed, padded)
    return emb.reshape((rounds * chunk,) + emb.shape[2:])[:b].astype(jnp.float32)


def previous_action_rows(data: Data) -> np.ndarray:
    """The split's rows that have a previous step in their episode (`t ≥ 1`), `[N'] int32` (host, numpy).

    Episodes are contiguous, so row `r - 1` holds `a_{t−1}` of row `r`.
    """
    rows = np.arange(data.obs.shape[0]) if data.rows is None else np.asarray(data.rows)
    return rows[np.asarray(data.t)[rows] >= 1].astype(np.int32)


def probe_inputs(cfg: LearnerConfig, params: Any, data: Data, chunk: int | None = None) -> ProbeInputs:
    """The embedding probe's inputs on one split: the policy's embeddings, `a_{t−1}` and `a_t` of every split
    row with `t ≥ 1` (`previous_action_rows`). Host code (the row count depends on the data).

    Args:
      cfg, params: the policy (see `policy_embeddings`).
      data: the split (`Data.rows` honoured).
      chunk: rows per forward pass (see `policy_embeddings`).

    Returns:
      A `ProbeInputs` of `[N', E]`, `[N', A]`, `[N', A] float32`.
    """
    rows = previous_action_rows(data)
    if rows.size == 0:
        raise ValueError("probe_inputs: the split has no row with t >= 1 (no previous action to predict)")
    action = jnp.asarray(data.action, jnp.float32)
    rows_j = jnp.asarray(rows)
    return ProbeInputs(embedding=policy_embeddings(cfg, params, data, rows_j, chunk),
                       previous_action=action[rows_j - 1], action=action[rows_j])


# -- the probe -------------------------------------------------------------------------------------------------------

def _check_pair(name: str, x: jax.Array, y: jax.Array) -> None:
    if x.ndim != 2 or y.ndim != 2 or x.shape[0] != y.shape[0] or x.shape[0] < 1:
        raise ValueError(f"{name}: inputs must be [N, D] and targets [N, A] with the same N >= 1, "
                         f"got {x.shape} and {y.shape}")


def probe_apply(params: ProbeParams, x: jax.Array) -> jax.Array:
    """The probe's predictions `[N, A] float32` for inputs `x [N, D]`, standardised as in training."""
    net = params.net["params"]
    action_dim, hidden = net["Dense_1"]["kernel"].shape[1], net["Dense_0"]["kernel"].shape[1]
    z = (jnp.asarray(x, jnp.float32) - params.x_mean) / params.x_std
    return ape_lib.ActionPredictor(action_dim, hidden).apply(params.net, z)


@functools.partial(jax.jit, static_argnames=("steps", "hidden", "batch"))
def fit_probe(key: jax.Array, x: jax.Array, y: jax.Array, steps: int = PROBE_STEPS, hidden: int = PROBE_HIDDEN,
              lr: float | jax.Array = PROBE_LR, batch: int = PROBE_BATCH) -> ProbeParams:
    """Fits a probe `x -> y` with MSE: ψ's architecture (one hidden layer, LeakyReLU(0.2)) on standardised inputs.

    The inputs are standardised with the training set's mean and standard deviation (kept in the
    returned parameters), so the probe reads embeddings of any scale alike. Adam, minibatches drawn
    uniformly with replacement, the loop a `lax.scan`; jitted (`steps`, `hidden`, `batch` static).

    Args:
      key: PRNG key, split into the initialisation's and the minibatches' (one `fold_in` per step).
      x: `[N, D] float32` inputs.
      y: `[N, A] float32` targets.
      steps: Adam steps.
      hidden: hidden units.
      lr: Adam's learning rate (traced).
      batch: minibatch rows.

    Returns:
      A `ProbeParams`.
    """
    x, y = jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32)
    _check_pair("fit_probe", x, y)
    mean, std = x.mean(axis=0), x.std(axis=0)
    std = jnp.where(std > 1e-6 * jnp.abs(mean), std, 1.0)  # a constant column (up to rounding) stays constant
    std = jnp.where(std > 0.0, std, 1.0)
    z = (x - mean) / std
    model = ape_lib.ActionPredictor(y.shape[1], hidden)
    key_init, key_batches = jax.random.split(key)
    net = model.init(key_init, z[:1])
    opt = optax.adam(lr)

    def loss_fn(p, rows):
        return jnp.mean(jnp.sum((model.apply(p, z[rows]) - y[rows]) ** 2, axis=-1))

    def update(carry, step):
        p, s = carry
        rows = jax.random.randint(jax.random.fold_in(key_batches, step), (batch,), 0, x.shape[0])
        grads = jax.grad(loss_fn)(p, rows)
        updates, s = opt.update(grads, s, p)
        return (optax.apply_updates(p, updates), s), None

    (net, _), _ = jax.lax.scan(update, (net, opt.init(net)), jnp.arange(steps))
    return ProbeParams(x_mean=mean, x_std=std, net=net)


def probe_mse(params: ProbeParams, x: jax.Array, y: jax.Array) -> jax.Array:
    """The probe's MSE on `x [N, D]`, `y [N, A]`: squared error summed over target dims, mean over rows;
    `[] float32`."""
    x, y = jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32)
    _check_pair("probe_mse", x, y)
    return jnp.mean(jnp.sum((probe_apply(params, x) - y) ** 2, axis=-1))


def probe_target(key: jax.Array, x_train: jax.Array, x_val: jax.Array, y_train: jax.Array, y_val: jax.Array,
                 steps: int = PROBE_STEPS, hidden: int = PROBE_HIDDEN, lr: float | jax.Array = PROBE_LR,
                 batch: int = PROBE_BATCH) -> TargetProbe:
    """How well inputs predict a target on held-out rows: a probe fitted on the training rows, scored on the
    validation rows (e.g. the embedding → `a_{t−1}`, or the embedding → `qvel_t`). Jit-able.

    Args:
      key: PRNG key (the probe's fit).
      x_train, x_val: `[N, D]`, `[N', D] float32` inputs.
      y_train, y_val: `[N, A]`, `[N', A] float32` targets.
      steps, hidden, lr, batch: the probe's fit (`fit_probe`).

    Returns:
      A `TargetProbe` (held-out MSE, the target's held-out spread around the training mean, their ratio).
    """
    x_train, x_val = jnp.asarray(x_train, jnp.float32), jnp.asarray(x_val, jnp.float32)
    y_train, y_val = jnp.asarray(y_train, jnp.float32), jnp.asarray(y_val, jnp.float32)
    _check_pair("probe_target (training rows)", x_train, y_train)
    _check_pair("probe_target (validation rows)", x_val, y_val)
    if x_train.shape[1] != x_val.shape[1] or y_train.shape[1] != y_val.shape[1]:
        raise ValueError(f"probe_target: training and validation dims differ: x {x_train.shape} vs "
                         f"{x_val.shape}, y {y_train.shape} vs {y_val.shape}")
    params = fit_probe(key, x_train, y_train, steps=steps, hidden=hidden, lr=lr, batch=batch)
    mse = probe_mse(params, x_val, y_val)
    baseline = jnp.mean(jnp.sum((y_val - y_train.mean(axis=0)) ** 2, axis=-1))
    return TargetProbe(mse=mse, baseline=baseline, ratio=mse / baseline)


def embedding_probe(key: jax.Array, emb_train: jax.Array, emb_val: jax.Array, prev_train: jax.Array,
                    prev_val: jax.Array, cur_train: jax.Array, cur_val: jax.Array, steps: int = PROBE_STEPS,
                    hidden: int = PROBE_HIDDEN, lr: float | jax.Array = PROBE_LR,
                    batch: int = PROBE_BATCH) -> EmbeddingProbe:
    """The FCA paper's Table 3: held-out MSE of `a_{t−1}` from the policy's embedding, against from `a_t` alone.

    The same probe (`probe_target`) is fitted twice on the training rows, once on the embedding and once on
    the current action, and scored on the validation rows. Rows are steps with `t ≥ 1` (`probe_inputs`
    builds them). Jit-able; vmaps over policies' embeddings.

    Args:
      key: PRNG key, split into the two probes'.
      emb_train, emb_val: `[N, E]`, `[N', E] float32`, the policy's embeddings of the rows.
      prev_train, prev_val: `[N, A]`, `[N', A] float32`, the expert's previous actions `a_{t−1}`.
      cur_train, cur_val: `[N, A]`, `[N', A] float32`, the expert's actions `a_t`.
      steps, hidden, lr, batch: each probe's fit (`fit_probe`).

    Returns:
      An `EmbeddingProbe`.
    """
    for name, (e, p, c) in {"training": (emb_train, prev_train, cur_train),
                            "validation": (emb_val, prev_val, cur_val)}.items():
        if not (jnp.shape(e)[0] == jnp.shape(p)[0] == jnp.shape(c)[0]) or jnp.shape(p) != jnp.shape(c):
            raise ValueError(f"embedding_probe: the {name} rows disagree: embedding {jnp.shape(e)}, previous "
                             f"action {jnp.shape(p)}, action {jnp.shape(c)}")
    key_embedding, key_action = jax.random.split(key)
    fit = dict(steps=steps, hidden=hidden, lr=lr, batch=batch)
    from_embedding = probe_target(key_embedding, emb_train, emb_val, prev_train, prev_val, **fit).mse
    from_action = probe_target(key_action, cur_train, cur_val, prev_train, prev_val, **fit).mse
    return EmbeddingProbe(prev_from_embedding=from_embedding, prev_from_action=from_action,
                          ratio=from_embedding / from_action)


# -- own-rollout predictability --------------------------------------------------------------------------------------

class _Rows(NamedTuple):
    action: np.ndarray  # [N, A] float32, episodes contiguous
    t: np.ndarray       # [N] int32


def _episode_rows(actions: np.ndarray, valid: np.ndarray) -> _Rows:
    """Valid steps of `[E, T, A]` episodes as rows, `t` counting each episode's valid steps from 0."""
    t = np.cumsum(valid, axis=1) - 1
    return _Rows(actions[valid].astype(np.float32), t[valid].astype(np.int32))


def _halves(name: str, actions: Any, valid: Any | None) -> tuple[_Rows, _Rows]:
    """A side's rollouts as (ψ's training rows: the first half of the episodes, held-out rows: the rest)."""
    actions = np.asarray(actions, np.float32)
    if actions.ndim != 3 or actions.shape[0] < 2 or actions.shape[1] < 1:
        raise ValueError(f"rollout_predictability: {name} actions must be [E, T, A] with E >= 2 episodes, "
                         f"got {actions.shape}")
    valid = np.ones(actions.shape[:2], bool) if valid is None else np.asarray(valid) > 0.5
    if valid.shape != actions.shape[:2]:
        raise ValueError(f"rollout_predictability: {name} valid mask must be {actions.shape[:2]}, "
                         f"got {valid.shape}")
    half = actions.shape[0] // 2
    return _episode_rows(actions[:half], valid[:half]), _episode_rows(actions[half:], valid[half:])


@functools.partial(jax.jit, static_argnames=("k", "steps", "batch"))
def _heldout_ape(key: jax.Array, train_action: jax.Array, train_t: jax.Array, val_action: jax.Array,
                 val_t: jax.Array, k: int, steps: int, batch: int) -> jax.Array:
    params, _ = ape_lib.fit(key, train_action, train_t, steps=steps, batch=batch, k=k)
    scored = (val_t >= 1).astype(jnp.float32)  # at t = 0 ψ's padded input holds a_0 itself
    return jnp.sum(ape_lib.errors(params, val_action, val_t, k) * scored) / jnp.maximum(scored.sum(), 1.0)


def rollout_predictability(key: jax.Array, policy_actions: Any, expert_actions: Any, k: int = ape_lib.K,
                           steps: int = PROBE_STEPS, batch: int = 512, policy_valid: Any | None = None,
                           expert_valid: Any | None = None) -> Predictability:
    """The FCA paper's Table 1: how predictable the policy's rollout actions are from its own past actions,
    relative to the expert's.

    Each side's episodes are laid out as rows with a time index `t` (only the steps its `valid` mask keeps,
    so steps after an episode ended are out); ψ (`ape_jax.ape.fit`: the previous `k` actions, one hidden
    layer of 300) is fitted on the first half of the episodes and its error (`ape_jax.ape.errors`, the
    squared error summed over action dims) averaged over the other half's steps with `t ≥ 1` (at `t = 0`
    ψ's padded input is the action itself, a free near-zero error that would favour the side with more,
    shorter episodes). Both sides keep the same number
    of steps, the longer cut to the shorter total (in episode order, so a cut episode keeps its first steps)
    in each half, so neither ψ has more to learn from. Host code: the masks decide the shapes, and the
    jitted fit compiles once per distinct row count.

    Args:
      key: PRNG key, split into the two fits'.
      policy_actions: `[E, T, A] float32`, the policy's rollouts (E >= 2).
      expert_actions: `[E', T', A] float32`, the expert's (E' >= 2).
      k: past actions per prediction.
      steps: ψ's Adam steps, on each side.
      batch: ψ's minibatch rows.
      policy_valid: `[E, T]` (bool or 0/1 float, e.g. `Trajectory.valid`), the steps inside each episode;
        None: every step.
      expert_valid: `[E', T']`, the same for the expert.

    Returns:
      A `Predictability`.
    """
    p_train, p_val = _halves("policy", policy_actions, policy_valid)
    e_train, e_val = _halves("expert", expert_actions, expert_valid)
    if p_train.action.shape[1] != e_train.action.shape[1]:
        raise ValueError(f"rollout_predictability: action dims differ: policy {np.shape(policy_actions)}, "
                         f"expert {np.shape(expert_actions)}")
    n_train = min(len(p_train.t), len(e_train.t))
    n_val = min(len(p_val.t), len(e_val.t))
    if n_train < 1 or n_val < 1:
        raise ValueError(f"rollout_predictability: no valid steps to fit or score on (training steps "
                         f"{len(p_train.t)} policy / {len(e_train.t)} expert, held-out {len(p_val.t)} / "
                         f"{len(e_val.t)})")
    key_policy, key_expert = jax.random.split(key)

    def score(key_side, train: _Rows, val: _Rows) -> float:
        return float(_heldout_ape(key_side, jnp.asarray(train.action[:n_train]), jnp.asarray(train.t[:n_train]),
                                  jnp.asarray(val.action[:n_val]), jnp.asarray(val.t[:n_val]),
                                  k=k, steps=steps, batch=batch))

    policy_mse, expert_mse = score(key_policy, p_train, p_val), score(key_expert, e_train, e_val)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = float(np.float64(policy_mse) / np.float64(expert_mse))
    return Predictability(policy_mse=policy_mse, expert_mse=expert_mse, ratio=ratio, train_rows=n_train,
                          val_rows=n_val)


# -- the verdict -----------------------------------------------------------------------------------------------------

def verdict(probe: EmbeddingProbe, predictability: Predictability,
            thresholds: Thresholds = THRESHOLDS) -> Verdict:
    """`"copycat"` when both criteria of `thresholds` hold, else `"not copycat"`, with the reasons.

    An undefined ratio (NaN or infinite: a reference error of zero) never holds.

    Args:
      probe: the policy's `EmbeddingProbe`.
      predictability: its `Predictability`.
      thresholds: the criteria (default `THRESHOLDS`, fixed before any result).

    Returns:
      A `Verdict`.
    """
    def criterion(what: str, ratio: float, threshold: float) -> tuple[bool, str]:
        held = math.isfinite(ratio) and ratio <= threshold
        sign = "<=" if held else (">" if math.isfinite(ratio) else "undefined, not <=")
        return held, f"{what}: ratio {ratio:.3g} {sign} {threshold} ({'held' if held else 'did not hold'})"

    e_held, e_reason = criterion("embedding probe, MSE(a_t-1 | embedding) / MSE(a_t-1 | a_t)",
                                 float(probe.ratio), thresholds.embedding_ratio)
    p_held, p_reason = criterion("own-rollout predictability, psi's MSE on the policy / on the expert",
                                 float(predictability.ratio), thresholds.predictability_ratio)
    return Verdict(label=COPYCAT if e_held and p_held else NOT_COPYCAT, embedding_held=e_held,
                   predictability_held=p_held, reasons=(e_reason, p_reason))
