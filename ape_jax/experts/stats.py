"""Action statistics of an expert's demonstrations: how rough its labels are.

The expert decides whether BC-OH copies (`docs/design.md`, "Rough experts"). Four numbers describe its labels,
each from the demonstrations alone (`[N, A]` actions with their episode ids and time indices, episodes contiguous):

- `outside`: the share of label entries outside the action range (a Gaussian's unbounded mean leaves it; a
  tanh-squashed one never does);
- `copy_error`: what copying the previous action costs, the mean over rows with a previous step in the same episode
  of Σ_d (a_t − a_{t−1})²;
- `psi_error`: ψ's held-out error (`ape_jax.ape`: the previous 9 actions → a_t, fitted on training rows, the mean
  APE over held-out rows): how predictable the labels are from their past;
- `variance`: Σ_d Var(a_d), the scale the two errors are read against.

    stats = action_stats(key, demos.action, demos.episode, demos.t, train_rows, val_rows, psi_steps=5_000)
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import ape


@dataclasses.dataclass(frozen=True)
class ActionStats:
    """The four statistics (module docstring) of one set of demonstrations, and what they were measured on.

    Attributes:
      outside: share of label entries outside [low, high], in [0, 1].
      copy_error: mean Σ_d (a_t − a_{t−1})² over rows with a previous step in their episode.
      psi_error: ψ's mean APE on the held-out rows.
      variance: Σ_d of the per-dimension variance of the labels.
      rows: label rows measured (outside, copy_error, variance).
      psi_train_rows, psi_val_rows: rows ψ was fitted on and scored on.
    """

    outside: float
    copy_error: float
    psi_error: float
    variance: float
    rows: int
    psi_train_rows: int
    psi_val_rows: int

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def outside_share(actions: np.ndarray, low: float | np.ndarray = -1.0, high: float | np.ndarray = 1.0) -> float:
    """Share of the entries of `actions` `[N, A]` outside `[low, high]` (scalars or `[A]` bounds)."""
    a = np.asarray(actions, np.float64)
    return float(np.mean((a < low) | (a > high)))


def copy_previous_error(actions: np.ndarray, episode: np.ndarray, t: np.ndarray) -> float:
    """Mean over rows with a previous step of their episode of Σ_d (a_t − a_{t−1})².

    Args:
      actions: `[N, A]` labels, episodes contiguous and in time order.
      episode: `[N] int` episode ids.
      t: `[N] int` time index within the episode.

    Returns:
      The mean, or NaN when no row has a previous step (episodes of one step).
    """
    a, episode, t = np.asarray(actions, np.float64), np.asarray(episode), np.asarray(t)
    follows = (episode[1:] == episode[:-1]) & (t[1:] == t[:-1] + 1)
    if not follows.any():
        return float("nan")
    return float(np.mean(np.sum((a[1:] - a[:-1]) ** 2, axis=-1)[follows]))


def action_variance(actions: np.ndarray) -> float:
    """Σ_d Var(a_d) of `actions` `[N, A]` (population variance per dimension, summed)."""
    return float(np.sum(np.var(np.asarray(actions, np.float64), axis=0)))


def psi_heldout_error(key: jax.Array, actions: np.ndarray, t: np.ndarray, train_rows: np.ndarray,
                      val_rows: np.ndarray, steps: int) -> float:
    """ψ's mean APE on `val_rows` after `ape.fit` on `train_rows` (past actions read from whole episodes).

    Args:
      key: PRNG key of ψ's fit.
      actions: `[N, A]` labels, episodes contiguous.
      t: `[N] int` time index within the episode.
      train_rows, val_rows: `[N_train]`, `[N_val]` int row indices into `actions`.
      steps: ψ's Adam steps.
    """
    actions, t = jnp.asarray(actions, jnp.float32), jnp.asarray(t, jnp.int32)
    params, _ = jax.jit(ape.fit, static_argnames=("steps",))(key, actions, t, steps=steps,
                                                             rows=jnp.asarray(train_rows, jnp.int32))
    return float(jnp.mean(ape.errors(params, actions, t)[jnp.asarray(val_rows)]))


def action_stats(key: jax.Array, actions: np.ndarray, episode: np.ndarray, t: np.ndarray, train_rows: np.ndarray,
                 val_rows: np.ndarray, psi_steps: int, low: float | np.ndarray = -1.0,
                 high: float | np.ndarray = 1.0) -> ActionStats:
    """The four statistics of a set of demonstrations (module docstring).

    Args:
      key: PRNG key of ψ's fit.
      actions: `[N, A]` labels as the expert gave them, episodes contiguous and in time order.
      episode, t: `[N] int` episode ids and time indices.
      train_rows, val_rows: ψ's training and held-out rows (e.g. the protocol's split).
      psi_steps: ψ's Adam steps.
      low, high: the action range (scalars or `[A]`).
    """
    return ActionStats(
        outside=outside_share(actions, low, high), copy_error=copy_previous_error(actions, episode, t),
        psi_error=psi_heldout_error(key, actions, t, train_rows, val_rows, psi_steps),
        variance=action_variance(actions), rows=int(np.shape(actions)[0]),
        psi_train_rows=int(len(train_rows)), psi_val_rows=int(len(val_rows)))
