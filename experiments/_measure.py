"""Measurements shared by the entry points: expert and random-policy returns."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

import envs


def random_policy(env: envs.Env) -> envs.Policy:
    """Uniform actions within the action bounds (clipped to [-1, 1])."""
    low, high = env.action_bounds
    low, high = jnp.maximum(low, -1.0), jnp.minimum(high, 1.0)
    return envs.stateless(lambda params, state, key: jax.random.uniform(key, low.shape, minval=low, maxval=high))


def returns(env: envs.Env, policy: envs.Policy, num_episodes: int, key: jax.Array, batch: int = 100) -> jax.Array:
    """Episode returns `[num_episodes] float32` of `policy`, run `batch` episodes at a time."""
    run = jax.jit(lambda k: envs.rollout(env, policy, None, k, min(batch, num_episodes)).returns)
    out = []
    for i in range(-(-num_episodes // batch)):
        out.append(run(jax.random.fold_in(key, i)))
    return jnp.concatenate(out)[:num_episodes]


def expert_and_random_returns(env: envs.Env, expert: Callable[[jax.Array], jax.Array], num_episodes: int,
                              key: jax.Array) -> dict:
    """Mean and std of the returns of `expert` (full observation -> action) and of a random policy."""
    key_expert, key_random = jax.random.split(key)
    expert_returns = returns(env, envs.from_observation(expert, expert=True, env=env), num_episodes, key_expert)
    random_returns = returns(env, random_policy(env), num_episodes, key_random)
    return {
        "episodes": num_episodes,
        "return_mean": float(expert_returns.mean()), "return_std": float(expert_returns.std()),
        "random_return_mean": float(random_returns.mean()), "random_return_std": float(random_returns.std()),
    }
