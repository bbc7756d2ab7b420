"""Own-rollout predictability: ψ's architecture fitted on half of a policy's own rollout episodes and scored on
the other half, against the same for the expert's executed actions. Host code around jitted fits."""

from __future__ import annotations

import functools
from typing import Any, NamedTuple
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import ape as ape_lib
from ape_jax.diagnostics.records import PROBE_STEPS, Predictability

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


class _Fits(NamedTuple):
    """ψ fits of one shape: F sides' rows padded to `S`/`S'` rows, each side's own row counts (traced)."""

    train_action: np.ndarray  # [F, S, A]
    train_t: np.ndarray       # [F, S]
    train_count: np.ndarray   # [F]
    val_action: np.ndarray    # [F, S', A]
    val_t: np.ndarray         # [F, S']
    val_count: np.ndarray     # [F]


def _power_of_two(n: int) -> int:
    """The least power of two >= `n` (n >= 1)."""
    return 1 << (n - 1).bit_length()


def _padded(rows: _Rows, n: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The first `n` rows, padded with zero rows (t = 0) to `size`: padding is never drawn nor scored."""
    action = np.zeros((size, rows.action.shape[1]), np.float32)
    t = np.zeros(size, np.int32)
    action[:n], t[:n] = rows.action[:n], rows.t[:n]
    return action, t


@functools.partial(jax.jit, static_argnames=("k", "steps", "batch"))
def _heldout_apes(keys: jax.Array, fits: _Fits, k: int, steps: int, batch: int) -> jax.Array:
    """ψ's held-out error `[F]` of each fit: fitted on its first `train_count` training rows, averaged over its
    first `val_count` held-out rows with `t ≥ 1`. One compiled program for every fit of a shape (`lax.map`)."""
    def one(args):
        key, train_action, train_t, train_count, val_action, val_t, val_count = args
        params, _ = ape_lib.fit(key, train_action, train_t, steps=steps, batch=batch, k=k, count=train_count)
        # at t = 0 ψ's padded input holds a_0 itself; the padding beyond val_count is not the side's
        scored = ((val_t >= 1) & (jnp.arange(val_t.shape[0]) < val_count)).astype(jnp.float32)
        return jnp.sum(ape_lib.errors(params, val_action, val_t, k) * scored) / jnp.maximum(scored.sum(), 1.0)

    return jax.lax.map(one, (keys, *fits))


def rollout_predictability_batch(key: jax.Array, policies: Sequence[tuple[Any, Any | None]], expert_actions: Any,
                                 expert_valid: Any | None = None, k: int = ape_lib.K, steps: int = PROBE_STEPS,
                                 batch: int = 512) -> list[Predictability]:
    """`rollout_predictability` of many policies against one expert, in one compiled program.

    Each policy's reference is the expert's rollouts cut to the policy's step counts (so it depends on the
    policy only through them: expert fits of equal counts are computed once). Every policy's ψ starts from
    the same key, and every expert fit from another, so two policies differ by their actions alone (common
    random numbers). Host code around one jitted `lax.map`: the sides are laid out as padded rows with their
    own counts, so a batch compiles once whatever its episodes' lengths.

    Args:
      key: PRNG key, split into the policies' fits' and the expert's.
      policies: per policy, `(actions [E, T, A], valid [E, T] or None)` (see `rollout_predictability`).
      expert_actions: `[E', T', A] float32`, the expert's rollouts (E' >= 2).
      expert_valid: `[E', T']` or None.
      k, steps, batch: ψ's fit (see `rollout_predictability`).

    Returns:
      One `Predictability` per policy, in order.
    """
    e_train, e_val = _halves("expert", expert_actions, expert_valid)
    sides, counts = [], []
    for i, (actions, valid) in enumerate(policies):
        p_train, p_val = _halves(f"policy {i}" if len(policies) > 1 else "policy", actions, valid)
        if p_train.action.shape[1] != e_train.action.shape[1]:
            raise ValueError(f"rollout_predictability: action dims differ: policy {np.shape(actions)}, "
                             f"expert {np.shape(expert_actions)}")
        n_train, n_val = min(len(p_train.t), len(e_train.t)), min(len(p_val.t), len(e_val.t))
        if n_train < 1 or n_val < 1:
            raise ValueError(f"rollout_predictability: no valid steps to fit or score on (training steps "
                             f"{len(p_train.t)} policy / {len(e_train.t)} expert, held-out {len(p_val.t)} / "
                             f"{len(e_val.t)})")
        sides.append((p_train, p_val)), counts.append((n_train, n_val))
    if not sides:
        return []
    expert_counts = list(dict.fromkeys(counts))  # the expert's fits: one per distinct pair of counts
    # padded to powers of two, so the evaluations of one sweep (at `eval_at` and at the end) and sweeps of
    # similar rollouts share one compiled fit; the padding changes no draw, only the held-out mean's
    # summation order (~1e-7 relative)
    size_train, size_val = (_power_of_two(max(c[i] for c in counts)) for i in (0, 1))
    fits = [(train, val, *c) for (train, val), c in zip(sides, counts)]
    fits += [(e_train, e_val, *c) for c in expert_counts]
    padded_train = [_padded(train, n, size_train) for train, _, n, _ in fits]
    padded_val = [_padded(val, n, size_val) for _, val, _, n in fits]
    stacked = _Fits(np.stack([a for a, _ in padded_train]), np.stack([t for _, t in padded_train]),
                    np.array([n for *_, n, _ in fits], np.int32), np.stack([a for a, _ in padded_val]),
                    np.stack([t for _, t in padded_val]), np.array([n for *_, n in fits], np.int32))
    key_policy, key_expert = jax.random.split(key)
    keys = jnp.stack([key_policy] * len(sides) + [key_expert] * len(expert_counts))
    mse = np.asarray(_heldout_apes(keys, jax.tree.map(jnp.asarray, stacked), k=k, steps=steps, batch=batch),
                     np.float64)
    expert_mse = dict(zip(expert_counts, mse[len(sides):]))
    out = []
    for i, c in enumerate(counts):
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = float(mse[i] / expert_mse[c])
        out.append(Predictability(policy_mse=float(mse[i]), expert_mse=float(expert_mse[c]), ratio=ratio,
                                  train_rows=c[0], val_rows=c[1]))
    return out


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
    shorter episodes). Both sides keep the same number of steps, the longer cut to the shorter total (in
    episode order, so a cut episode keeps its first steps) in each half, so neither ψ has more to learn
    from. Host code around a jitted fit (`rollout_predictability_batch`, which does many policies at once).

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
    return rollout_predictability_batch(key, [(policy_actions, policy_valid)], expert_actions, expert_valid,
                                        k=k, steps=steps, batch=batch)[0]


def demonstration_rollouts(action: Any, episode: Any) -> tuple[np.ndarray, np.ndarray]:
    """Demonstrations (rows, episodes contiguous) as rollouts: `(actions [E, T, A], valid [E, T] bool)`, each
    episode's steps first, padded to the longest episode. The expert's side of the predictability when its
    demonstrations were collected without noise (as every sweep's are): they are its own rollouts.

    Args:
      action: `[N, A]`, the expert's actions: for the predictability the executed ones
        (`Demonstrations.executed`, clipped to the action range as the policy's rollout actions are), not the
        labels, which `protocol.labels = "raw"` leaves unbounded.
      episode: `[N]`, episode ids (contiguous runs).
    """
    action, episode = np.asarray(action, np.float32), np.asarray(episode)
    starts = np.flatnonzero(np.r_[True, episode[1:] != episode[:-1]])
    ends = np.r_[starts[1:], len(episode)]
    length = int((ends - starts).max()) if len(starts) else 0
    actions = np.zeros((len(starts), length, action.shape[1]), np.float32)
    valid = np.zeros((len(starts), length), bool)
    for e, (a, b) in enumerate(zip(starts, ends)):
        actions[e, : b - a], valid[e, : b - a] = action[a:b], True
    return actions, valid
