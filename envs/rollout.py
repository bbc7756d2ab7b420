"""The one way the project steps environments: `lax.scan` over steps, `vmap` over episodes.

`reset` and `step` of the same episode always run inside one traced program,
so no state crosses a jit boundary (Brax's weak types would otherwise retrace).
Episodes end at their first `done` or after `num_steps`; after `done` the
state is frozen and the remaining steps are marked invalid, so sums over
`reward * valid` are episode returns.

A policy is a pair of pure functions with explicit parameters, so evaluation
can vmap over policies as well as episodes:

    init(params, state) -> carry                       # e.g. an observation history
    act(params, carry, state, key) -> (action, carry)
"""

from __future__ import annotations

from typing import Any, NamedTuple
from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from envs.base import Env, State


class Policy(NamedTuple):
    """A (possibly stateful) policy: see the module docstring."""

    init: Callable[[Any, State], Any]
    act: Callable[[Any, Any, State, jax.Array], tuple[jax.Array, Any]]


def stateless(fn: Callable[[Any, State, jax.Array], jax.Array]) -> Policy:
    """Wraps `fn(params, state, key) -> action` as a `Policy` with no carry."""
    return Policy(init=lambda params, state: (), act=lambda params, carry, state, key: (fn(params, state, key), carry))


def from_observation(fn: Callable[[jax.Array], jax.Array], expert: bool = False, env: Env | None = None) -> Policy:
    """A parameter-free policy of the observation: `fn(obs) -> action`.

    With `expert=True` it reads `env.expert_observation(state)` (the full
    state) instead of `state.obs`.
    """
    if expert and env is None:
        raise ValueError("from_observation(expert=True) needs env")
    view = env.expert_observation if expert else (lambda s: s.obs)
    return stateless(lambda params, state, key: fn(view(state)))


@struct.dataclass
class Trajectory:
    """A batch of rollouts; every field has leading dims `[N episodes, T steps]`.

    Attributes:
      obs: observation the policy saw before acting, `[N, T, *obs_shape]`.
      action: action taken, `[N, T, action_size] float32`.
      reward: reward of the step, `[N, T] float32` (0 once the episode ended).
      done: 1 if the state after the step is terminal, `[N, T] float32`.
      valid: 1 for steps inside the episode, `[N, T] float32`.
      extra: whatever `record(state)` returned for the pre-step state, stacked.
      final: the `State` after the last step, leading dim `[N]`.
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    done: jax.Array
    valid: jax.Array
    extra: Any
    final: State

    @property
    def returns(self) -> jax.Array:
        """Episode returns, `[N] float32`."""
        return jnp.sum(self.reward * self.valid, axis=-1)

    @property
    def lengths(self) -> jax.Array:
        """Episode lengths in steps, `[N] int32`."""
        return jnp.sum(self.valid, axis=-1).astype(jnp.int32)


def rollout(
    env: Env,
    policy: Policy,
    params: Any,
    key: jax.Array,
    num_episodes: int,
    num_steps: int | None = None,
    record: Callable[[State], Any] | None = None,
) -> Trajectory:
    """Runs `num_episodes` episodes of `num_steps` steps; traceable (call it under `jit`).

    Args:
      env: the environment.
      policy: a `Policy`.
      params: the policy's parameters (any pytree, `None` for none).
      key: PRNG key; episode i resets with the i-th of `num_episodes` keys split
        from it, so a batch's episodes are independent and reproducible.
      num_episodes: episodes in the batch (vmapped).
      num_steps: steps per episode (scanned); defaults to `env.episode_length`.
      record: optional `state -> pytree` stored for each pre-step state
        (e.g. the simulator state, or the expert's observation).

    Returns:
      A `Trajectory` with leading dims `[num_episodes, num_steps]`.
    """
    num_steps = env.episode_length if num_steps is None else int(num_steps)
    if num_episodes < 1 or num_steps < 1:
        raise ValueError(f"num_episodes and num_steps must be >= 1, got {num_episodes} and {num_steps}")
    record = record or (lambda state: ())
    key_reset, key_act = jax.random.split(key)

    def episode(key_reset_i, key_act_i):
        state = env.reset(key_reset_i)
        carry = policy.init(params, state)

        def step(loop, t):
            state, carry = loop
            action, carry = policy.act(params, carry, state, jax.random.fold_in(key_act_i, t))
            action = jnp.asarray(action, jnp.float32)
            nxt = env.step(state, action)
            alive = state.done <= 0
            nxt = jax.tree.map(lambda a, b: jnp.where(alive, a, b), nxt, state)
            out = (state.obs, action, nxt.reward * alive, nxt.done, alive.astype(jnp.float32), record(state))
            return (nxt, carry), out

        (final, _), (obs, action, reward, done, valid, extra) = jax.lax.scan(
            step, (state, carry), jnp.arange(num_steps)
        )
        return Trajectory(obs=obs, action=action, reward=reward, done=done, valid=valid, extra=extra, final=final)

    return jax.vmap(episode)(jax.random.split(key_reset, num_episodes), jax.random.split(key_act, num_episodes))
