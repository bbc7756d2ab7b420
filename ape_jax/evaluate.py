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

**A method's own policy.** A trained policy is `cfg.model()` acting on its last `H` observations, unless its
method's record gives `Method.runtime(cfg, settings) -> Runtime` (ACT's action chunks with their temporal
ensemble, PrimeNet's prime network feeding the history policy): then evaluation, the loss analysis, the copycat
probes and the videos read it through that `Runtime` (`runtime_of`).
"""

from __future__ import annotations

from typing import Any, NamedTuple
from collections.abc import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp

import envs
from ape_jax import ape as ape_lib
from ape_jax import methods, weighting
from ape_jax.grid import in_blocks
from ape_jax.history import history_index
from ape_jax.learner import Data, Learner, LearnerConfig, action_errors, dataset_losses, make_train


class Runtime(NamedTuple):
    """How a method's trained policies are read where they are not `cfg.model()` acting on its history.

    A method's record gives `Method.runtime(cfg, settings) -> Runtime`: `cfg` the program's
    `LearnerConfig`, `settings` the hyperparameters of each run of the group (`Method.settings`' dicts, in order).

    Attributes:
      apply: `apply(variables, x, return_embedding=False)`, as `cfg.model().apply`: the network on the policy
        input `x` (`[B, ...]`, `make_train(cfg).policy_input` of the last `cfg.history` observations) -> the
        action at `t` `[B, A]`; with `return_embedding=True` `(action, embedding [B, E])`, what the copycat
        probes read. The loss analysis scores this action.
      policy: `policy(obs_mean, obs_std, env) -> envs.Policy`: the run-time policy (stateful where the method
        is, e.g. a buffer of past predictions), its params the policy's variables; None: `history_policy`
        acting with `apply`.
    """

    apply: Callable[..., Any]
    policy: Callable[[Any, Any, envs.Env], envs.Policy] | None = None


def runtime_factory(method: str) -> Callable[[LearnerConfig, Sequence[Mapping[str, float]]], Runtime] | None:
    """`method`'s `Method.runtime`; None where it has none (its policy is `cfg.model()`) or `method` is not
    registered in this process (a plugin of a file evaluated again)."""
    try:
        return methods.get(method).runtime
    except methods.MethodError:
        return None


def runtime_of(cfg: LearnerConfig, method: str, settings: Sequence[Mapping[str, float]]) -> Runtime | None:
    """The `Runtime` of `method`'s policies trained under `cfg` at `settings` (one dict per policy), or None: a
    plain `cfg.model()` (`runtime_factory`)."""
    make = runtime_factory(method)
    return None if make is None else make(cfg, settings)


def history_policy(cfg: LearnerConfig, obs_mean: jax.Array | None, obs_std: jax.Array | None,
                   env: envs.Env, apply: Callable[..., Any] | None = None) -> envs.Policy:
    """A trained policy as an `envs.Policy` whose carry is the observation history `[H, *obs_shape]`; `apply`
    (a `Runtime`'s) applies the network, None: `cfg.model().apply`."""
    apply = apply or cfg.model().apply
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
        action = apply(params, learner.policy_input(history[None]))[0]
        return jnp.clip(action, low, high), history

    return envs.Policy(init=init, act=act)


def runtime_policy(cfg: LearnerConfig, obs_mean: jax.Array | None, obs_std: jax.Array | None, env: envs.Env,
                   runtime: Runtime | None = None) -> envs.Policy:
    """The policy a trained network acts as: `runtime`'s own, else `history_policy` (with `runtime.apply`)."""
    if runtime is not None and runtime.policy is not None:
        return runtime.policy(obs_mean, obs_std, env)
    return history_policy(cfg, obs_mean, obs_std, env, None if runtime is None else runtime.apply)


def make_evaluator(env: envs.Env, cfg: LearnerConfig, obs_mean: jax.Array | None, obs_std: jax.Array | None,
                   episodes: int, steps: int | None = None, expert: Callable[[jax.Array], jax.Array] | None = None,
                   ape_params: Any = None, ape_scale: float = 1.0,
                   keep_actions: bool = False, width: int | None = None,
                   runtime: Runtime | None = None) -> Callable[[Any, jax.Array], dict]:
    """A jitted `(params [P, ...], key) -> {"return": [P, E], "length": [P, E], ...}`.

    `runtime`: how the policies act where they are not `cfg.model()` on their history (`runtime_policy`).

    `width`: the policies go `width` at a time through one executable (`grid.in_blocks`), so a policy's
    episodes do not depend on how many are evaluated with it; None: all `P` in one call.

    `expert` (`full observation -> action`) adds `imitation_error`, and
    `ape_params` (ψ) with `ape_scale` (the training mean APE) `rollout_ape`
    (see the module docstring). `keep_actions` adds the rollouts' actions
    `"actions": [P, E, T, A]` and `"valid": [P, E, T]` (for
    `ape_jax.diagnostics`' own-rollout predictability).
    """
    policy = runtime_policy(cfg, obs_mean, obs_std, env, runtime)
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


def runtime_learner(cfg: LearnerConfig, runtime: Runtime | None = None) -> Learner:
    """`make_train(cfg)`, its per-sample loss (`(params, data, idx) -> [B]`) that of `runtime.apply`'s action
    where a `runtime` is given (the rows' histories built as the learner builds them)."""
    learner = make_train(cfg)
    if runtime is None:
        return learner

    def per_sample_loss(params, data: Data, idx: jax.Array) -> jax.Array:
        x = learner.policy_input(data.obs[history_index(data.t, idx, cfg.history)])
        return action_errors(cfg, runtime.apply(params, x), data.action[idx])

    return learner._replace(per_sample_loss=per_sample_loss)


def loss_analysis(cfg: LearnerConfig, params: Any, data: Data, changepoint_frac: float = 0.1,
                  width: int | None = None, runtime: Runtime | None = None) -> dict:
    """The paper's Table 3 for a batch of policies on one split (`runtime`: their action, `runtime_learner`).

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
    learner = runtime_learner(cfg, runtime)

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
