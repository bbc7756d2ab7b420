"""The one way the project steps environments: `lax.scan` over steps, `vmap` over episodes.

`rollout` runs `reset` and every `step` of an episode inside one traced program;
`start` and `advance` run the same steps as several (a long collection the host
can stop between chunks), the state crossing jit boundaries with the strong
types `Env.reset` and `Env.step` give it, so no chunk retraces.
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
        step = _stepper(env, policy, params, key_act_i, record)
        (final, _), (obs, action, reward, done, valid, extra) = jax.lax.scan(
            step, (state, carry), jnp.arange(num_steps)
        )
        return Trajectory(obs=obs, action=action, reward=reward, done=done, valid=valid, extra=extra, final=final)

    return jax.vmap(episode)(jax.random.split(key_reset, num_episodes), jax.random.split(key_act, num_episodes))


def _stepper(env: Env, policy: Policy, params: Any, key_act: jax.Array, record: Callable[[State], Any]):
    """The scan body of one episode: `((state, carry), t) -> ((next, carry), (obs, action, reward, done, valid,
    extra))`, the state frozen once `done`; the action's key is `fold_in(key_act, t)`."""

    def step(loop, t):
        state, carry = loop
        action, carry = policy.act(params, carry, state, jax.random.fold_in(key_act, t))
        action = jnp.asarray(action, jnp.float32)
        nxt = env.step(state, action)
        alive = state.done <= 0
        nxt = jax.tree.map(lambda a, b: jnp.where(alive, a, b), nxt, state)
        out = (state.obs, action, nxt.reward * alive, nxt.done, alive.astype(jnp.float32), record(state))
        return (nxt, carry), out

    return step


@struct.dataclass
class Running:
    """Episodes part-way through a rollout run in chunks (`start`, `advance`); every field has leading dim `[N]`.

    Attributes:
      state: each episode's current `State` (frozen once `done`).
      carry: the policy's carry.
      key_act: each episode's action key (`fold_in(key_act, t)` at step t).
      t: `[N] int32`, steps taken so far (the same for every episode).
    """

    state: State
    carry: Any
    key_act: jax.Array
    t: jax.Array

    @property
    def all_done(self) -> jax.Array:
        """`[] bool`: every episode has ended (further steps are all invalid)."""
        return jnp.all(self.state.done > 0)


def start(env: Env, policy: Policy, params: Any, key: jax.Array, num_episodes: int) -> Running:
    """Resets `num_episodes` episodes as `rollout` does with the same `key` (traceable); `advance` steps them.

    `rollout(env, policy, params, key, N, T)` and `start` then `advance` in chunks of steps that sum to T give the
    same steps (the same reset keys and per-step action keys): a long rollout can run as several short jitted
    calls, so the host can stop it between them (Ctrl-C) without waiting for the whole episode.
    """
    if num_episodes < 1:
        raise ValueError(f"num_episodes must be >= 1, got {num_episodes}")
    key_reset, key_act = jax.random.split(key)

    def one(key_reset_i, key_act_i):
        state = env.reset(key_reset_i)
        return Running(state=state, carry=policy.init(params, state), key_act=key_act_i, t=jnp.zeros((), jnp.int32))

    return jax.vmap(one)(jax.random.split(key_reset, num_episodes), jax.random.split(key_act, num_episodes))


def advance(env: Env, policy: Policy, params: Any, running: Running, num_steps: int,
            record: Callable[[State], Any] | None = None) -> tuple[Running, Trajectory]:
    """Steps the episodes of `running` `num_steps` more steps (traceable; call it under `jit`).

    Returns:
      `(running, trajectory)`: the episodes after the chunk, and the chunk's `Trajectory` (leading dims
      `[N, num_steps]`; its `final` is the state after the chunk). Chunks concatenated along axis 1 are
      `rollout`'s trajectory.
    """
    if num_steps < 1:
        raise ValueError(f"num_steps must be >= 1, got {num_steps}")
    record = record or (lambda state: ())

    def episode(r: Running):
        step = _stepper(env, policy, params, r.key_act, record)
        (final, carry), (obs, action, reward, done, valid, extra) = jax.lax.scan(
            step, (r.state, r.carry), r.t + jnp.arange(num_steps)
        )
        traj = Trajectory(obs=obs, action=action, reward=reward, done=done, valid=valid, extra=extra, final=final)
        return r.replace(state=final, carry=carry, t=r.t + num_steps), traj

    return jax.vmap(episode)(running)
