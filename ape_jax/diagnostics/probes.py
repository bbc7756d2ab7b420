"""The embedding probe: a frozen policy's embeddings of demonstration rows, and a small MLP fitted on them to
predict a target (the previous action, the velocity) against a reference input; `probe_policies` runs both probes
on every policy of a batch. Pure and jit-able."""

from __future__ import annotations

import functools
from typing import Any
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ape_jax import ape as ape_lib
from ape_jax.history import history_index
from ape_jax.learner import Data, LearnerConfig, make_train
from ape_jax.diagnostics.records import (PROBE_BATCH, PROBE_HIDDEN, PROBE_LR, PROBE_STEPS, EmbeddingProbe,
                                        ProbeInputs, ProbeParams, TargetProbe)

# -- the policy's embedding ------------------------------------------------------------------------------------------

def policy_embeddings(cfg: LearnerConfig, params: Any, data: Data, idx: jax.Array,
                      chunk: int | None = None, apply: Callable[..., Any] | None = None) -> jax.Array:
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
      apply: the network as `cfg.model().apply` (None: that), for a method whose trained policy is another one
        (`ape_jax.evaluate.Runtime.apply`).

    Returns:
      `[B, E] float32`.
    """
    idx = jnp.asarray(idx, jnp.int32)
    if idx.ndim != 1 or idx.shape[0] < 1:
        raise ValueError(f"policy_embeddings: idx must be [B] with B >= 1, got shape {idx.shape}")
    apply, learner = apply or cfg.model().apply, make_train(cfg)
    b = idx.shape[0]
    chunk = max(1, min(chunk or (256 if cfg.images else 4096), b))
    rounds = -(-b // chunk)
    padded = idx[jnp.arange(rounds * chunk) % b].reshape(rounds, chunk)  # the last chunk wraps; cut off below

    def embed(rows):
        x = learner.policy_input(data.obs[history_index(data.t, rows, cfg.history)])
        return apply(params, x, return_embedding=True)[1]

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
    """Fits a probe `x -> y` with MSE: ψ's shape (one hidden layer, LeakyReLU(0.2); `hidden` units, 100 by
    default against ψ's 300) on standardised inputs.

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


# -- every policy of a batch ----------------------------------------------------------------------------------------

@functools.partial(jax.jit, static_argnames=("cfg", "steps", "apply"))
def probe_policies(key: jax.Array, cfg: LearnerConfig, params: Any, train: Data, val: Data, rows: tuple,
                   targets: tuple, steps: int, apply: Callable[..., Any] | None = None) -> tuple[jax.Array, jax.Array]:
    """Per policy (a `lax.map`, so one policy's embeddings are in memory at a time): the probe's held-out MSE of
    `a_{t−1}` from its embedding `[P]`, and the velocity probe's ratio `[P]` (NaN without velocities)."""
    rows_train, rows_val = rows
    prev_train, prev_val, vel_train, vel_val = targets
    key_prev, key_vel = jax.random.split(key)

    def one(p):
        e_train = policy_embeddings(cfg, p, train, rows_train, apply=apply)
        e_val = policy_embeddings(cfg, p, val, rows_val, apply=apply)
        prev = probe_target(key_prev, e_train, e_val, prev_train, prev_val, steps=steps).mse
        vel = (jnp.float32(jnp.nan) if vel_train is None else
               probe_target(key_vel, e_train, e_val, vel_train, vel_val, steps=steps).ratio)
        return prev, vel

    return jax.lax.map(one, params)
