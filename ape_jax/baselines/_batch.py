"""The minibatch the penalised BC learners (RAP, PALR, MINE) draw each iteration: BC-OH's, with `a_{t−1}` beside it.

The rows, the observation history and the augmentation key are drawn exactly as `ape_jax.learner.make_train`
draws them (`Data.sample` on `fold_in(key, step)`, `history_index`, `augment` on `fold_in(key_step, 2)`), so a
learner whose extra term is weighted 0 sees BC-OH's batches; keys `fold_in(key_step, k)` with `k >= 3` are
free for a learner's own randomness. The previous action is read from the whole episode as FCA reads it
(`ape_jax.baselines.fca`): at an episode's first step it repeats the first action, so `a_{t−1} = a_t` there.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ape_jax.history import history_index
from ape_jax.learner import Data, Learner, LearnerConfig, action_errors, augment

OWN_KEYS = 3  # `fold_in(key_step, k)` for k < OWN_KEYS are BC-OH's (rows; dropout 1, augmentation 2)


class Batch(NamedTuple):
    """One iteration's minibatch.

    Attributes:
      x: `[B, ...] float32`, the policy's input (`Learner.policy_input` of the observation history).
      action: `[B, A] float32`, the expert's `a_t`.
      previous: `[B, A] float32`, the expert's `a_{t−1}` (`a_t` at an episode's first step).
    """

    x: jax.Array
    action: jax.Array
    previous: jax.Array


def sample_batch(cfg: LearnerConfig, base: Learner, data: Data, key_step: jax.Array) -> Batch:
    """BC-OH's minibatch of iteration `key_step` (`fold_in(run key, step)`), with the previous actions."""
    _, idx = data.sample(key_step, cfg.batch_size)
    history = augment(cfg, jax.random.fold_in(key_step, 2), data.obs[history_index(data.t, idx, cfg.history)])
    previous = data.action[history_index(data.t, idx, 1, offset=1)[:, 0]]
    return Batch(x=base.policy_input(history), action=data.action[idx], previous=previous)


def errors(cfg: LearnerConfig, predicted: jax.Array, target: jax.Array) -> jax.Array:
    """`[B]` the project's per-sample loss: squared error (`"l2"`) or absolute error (`"l1"`) summed over action
    dimensions, as `make_train` computes it."""
    return action_errors(cfg, predicted, target)


def action_statistics(data: Data) -> tuple[jax.Array, jax.Array]:
    """`([A], [A]) float32`: the mean and standard deviation of the split rows' actions (1 where a dimension is
    constant), to standardise actions as PALR's code does before its kernels see them."""
    action = data.action if data.rows is None else data.action[data.rows]
    mean, std = action.mean(axis=0), action.std(axis=0)
    return mean, jnp.where(std > 1e-6, std, 1.0)
