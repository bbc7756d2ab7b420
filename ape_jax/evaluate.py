"""Evaluation of trained policies, jit-compiled and vmapped over policies × episodes; the loss analysis.

    run = make_evaluator(env, cfg, obs_mean, obs_std, episodes=10)
    out = run(params, key)       # params leaves [P, ...] -> {"return": [P, E], "length": [P, E], ...}

Each policy keeps its own history of the last `H` observations, padded at the
episode start by repeating the first observation, exactly as in training;
state observations are standardised with the training set's statistics.
Every policy sees the same `E` episodes (common random numbers), so
differences between methods are not differences between start states.
An environment with metrics of its own (`env.episode_metric_names`, e.g.
the driving sandbox's `success`, `red_light_violations`, …) adds them.

Copycat diagnostics (given the expert, and ψ of `ape_jax.ape`), per episode,
over the steps before it ends:

- `imitation_error`: `mean_t Σ_d (a_t − a*(s_t))²`, the policy's action against
  the expert's action on the states *the policy* visits (the expert sees the
  full state);
- `rollout_ape`: the mean APE of the policy's own action sequence, ψ predicting
  each of its actions from its previous 9, divided by the training set's mean
  APE: the expert's demonstrations score about 1, and a policy that copies its
  previous action is more predictable than the expert, so scores lower.
"""

from __future__ import annotations

from typing import Any
from collections.abc import Callable

import jax
import jax.numpy as jnp

import envs
from ape_jax import ape as ape_lib
from ape_jax import weighting
from ape_jax.grid import in_blocks
from ape_jax.learner import Data, LearnerConfig, dataset_losses, make_train


def history_policy(cfg: LearnerConfig, obs_mean: jax.Array | None, obs_std: jax.Array | None,
                   env: envs.Env) -> envs.Policy:
    """A trained policy as an `envs.Policy` whose carry is the observation history `[H, *obs_shape]`."""
    model = cfg.model()
    learner = make_train(cfg)
    low, high = env.action_bounds

    def observe(state):
        obs = state.obs
        if obs_mean is not None:
            obs = (obs - obs_mean) / obs_std
        return obs

    def init(params, state):
        return jnp.repeat(observe(state)[None], cfg.history, axis=0)

    def act(params, carry, state, key):
        history = jnp.concatenate([carry[1:], observe(state)[None]])
        action = model.apply(params, learner.policy_input(history[None]))[0]
        return jnp.clip(action, low, high), history

    return envs.Policy(init=init, act=act)


def make_evaluator(env: envs.Env, cfg: LearnerConfig, obs_mean: jax.Array | None, obs_std: jax.Array | None,
                   episodes: int, steps: int | None = None, expert: Callable[[jax.Array], jax.Array] | None = None,
                   ape_params: Any = None, ape_scale: float = 1.0,
                   keep_actions: bool = False, width: int | None = None) -> Callable[[Any, jax.Array], dict]:
    """A jitted `(params [P, ...], key) -> {"return": [P, E], "length": [P, E], ...}`.

    `width`: the policies go `width` at a time through one executable (`grid.in_blocks`), so a policy's
    episodes do not depend on how many are evaluated with it; None: all `P` in one call.

    `expert` (`full observation -> action`) adds `imitation_error`, and
    `ape_params` (ψ) with `ape_scale` (the training mean APE) `rollout_ape`
    (see the module docstring). `keep_actions` adds the rollouts' actions
    `"actions": [P, E, T, A]` and `"valid": [P, E, T]` (for
    `ape_jax.diagnostics`' own-rollout predictability).
    """
    policy = history_policy(cfg, obs_mean, obs_std, env)
    own_metrics = bool(env.episode_metric_names)

    def record(state):
        out = {}
        if own_metrics:
            out["sim"] = env.sim_state(state)
        if expert is not None:
            out["expert_action"] = jnp.asarray(expert(env.expert_observation(state)), jnp.float32)
        return out

    def per_episode(values, valid):  # [E, T] -> [E], the mean over each episode's steps
        return jnp.sum(values * valid, axis=1) / jnp.maximum(jnp.sum(valid, axis=1), 1.0)

    def one(params, key):
        traj = envs.rollout(env, policy, params, key, episodes, steps, record=record)
        out = {"return": traj.returns, "length": traj.lengths.astype(jnp.float32)}
        if own_metrics:
            out.update(jax.vmap(env.episode_metrics)(traj.extra["sim"], traj.final, traj.valid))
        if expert is not None:
            err = jnp.sum((traj.action - traj.extra["expert_action"]) ** 2, axis=-1)
            out["imitation_error"] = per_episode(err, traj.valid)
        if ape_params is not None:
            t = jnp.arange(traj.action.shape[1])
            ape = jax.vmap(lambda a: ape_lib.errors(ape_params, a, t))(traj.action) / ape_scale
            out["rollout_ape"] = per_episode(ape, traj.valid)
        if keep_actions:
            out["actions"], out["valid"] = traj.action, traj.valid
        return out

    return in_blocks(jax.jit(jax.vmap(one, in_axes=(0, None))), width)


def normalized(returns: jax.Array | float, expert: float, random: float) -> Any:
    """`100 · (R − R_random) / (R_expert − R_random)`."""
    return 100.0 * (returns - random) / (expert - random)


def loss_analysis(cfg: LearnerConfig, params: Any, data: Data, changepoint_frac: float = 0.1,
                  width: int | None = None) -> dict:
    """The paper's Table 3 for a batch of policies on one split.

    Args:
      params: policies, leaves `[P, ...]`.
      data: a split with its (normalised) APE.
      changepoint_frac: the top fraction of APE counted as changepoints.

    Returns:
      `{"unweighted", "changepoint", "copycat"}`, each `[P] float32`: the mean
      unweighted per-sample loss on all samples, on the top `changepoint_frac`
      by APE, and on the rest.

    State policies are vmapped together over 4,096-row chunks; image policies
    go one after another over 256-row chunks, so that memory holds one
    policy's activations on 256 frames rather than every policy's on 4,096
    (9 GB for nine 32×32 policies). `width`: state policies go `width` at a time through one executable
    (`grid.in_blocks`); None: all together.
    """
    learner = make_train(cfg)

    def one(p, data):  # data is an argument, not a closed-over constant XLA would try to fold
        losses = dataset_losses(learner, p, data)
        cp = (weighting.step(data.ape, changepoint_frac, 2.0) > 1.0).astype(jnp.float32)
        return {"unweighted": losses.mean(),
                "changepoint": jnp.sum(losses * cp) / jnp.maximum(cp.sum(), 1.0),
                "copycat": jnp.sum(losses * (1 - cp)) / jnp.maximum((1 - cp).sum(), 1.0)}

    @jax.jit
    def run(params, data):
        if cfg.images:
            return jax.lax.map(lambda p: one(p, data), params)
        return jax.vmap(one, in_axes=(0, None))(params, data)

    return in_blocks(run, None if cfg.images else width)(params, data)
