"""Soft actor-critic for the experts, built from `brax.training`'s SAC parts.

Brax's own `sac.train` runs a whole training in one call and, on restore,
brings back only the policy: the critics, the optimiser states, the entropy
temperature and the replay buffer start afresh. Training an expert on a 2-core
CPU takes hours and sessions end without warning, so this module assembles the
same algorithm from Brax's pieces (`sac.networks`, `sac.losses`,
`gradients.gradient_update_fn`, `replay_buffers.UniformSamplingQueue`,
`acting.actor_step`, `acting.Evaluator`, `acme.running_statistics`) behind a
state that is a plain pytree, checkpointed whole by `experiments.train_expert`:

    trainer = make_trainer(brax_env, SACConfig(...))
    state = trainer.init(key)                      # TrainState: params, optimisers, buffer
    state, metrics = trainer.epoch(state)          # cfg.epoch_steps env steps, jitted
    mean, std = trainer.evaluate(state.policy)     # deterministic policy, Brax's Evaluator
    spec = trainer.policy_spec(state.policy)       # what `envs.experts.save` writes

`run_epoch` adds the evaluation and best-policy bookkeeping, and `Checkpoints`
saves and restores `(state, best, meta)` with orbax; a restored state trains on
exactly as the uninterrupted one would.

The environment state is not part of `TrainState`: a resumed run resets its
environments, which costs nothing but the episodes in flight.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from typing import Any, NamedTuple
from collections.abc import Callable

import flax
import jax
import jax.numpy as jnp
import optax
from envs._quiet import brax_envs  # first: MuJoCo warnings go to Python, not to MUJOCO_LOG.TXT in the working directory
from brax.training import acting, gradients, replay_buffers
from brax.training.acme import running_statistics, specs
from brax.training.agents.sac import losses as sac_losses
from brax.training.agents.sac import networks as sac_networks
from brax.training.types import Transition


@dataclasses.dataclass(frozen=True)
class SACConfig:
    """Hyperparameters of one expert training run (recorded in the expert's card).

    `num_envs` environments step in parallel; after each of their steps the
    learner takes `grad_updates_per_step` gradient steps on minibatches of
    `batch_size`, so the update-to-data ratio is `grad_updates_per_step /
    num_envs`. `epoch_steps` environment steps pass between evaluations and
    checkpoints. Each epoch starts fresh episodes (the environments live inside
    one jitted epoch and are not checkpointed), so training episodes last at
    most `epoch_steps / num_envs` steps (400 with the shipped settings); the
    locomotion gaits this trains are periodic and evaluation runs the full
    `episode_length`.
    """

    num_timesteps: int = 1_000_000
    num_envs: int = 32
    grad_updates_per_step: int = 16
    batch_size: int = 256
    learning_rate: float = 3e-4
    discounting: float = 0.99
    reward_scaling: float = 1.0
    tau: float = 0.005
    min_replay_size: int = 10_000
    hidden_layer_sizes: tuple[int, ...] = (256, 256)
    episode_length: int = 1000
    epoch_steps: int = 20_000
    num_eval_envs: int = 16
    seed: int = 0

    def __post_init__(self):
        for name in ("num_timesteps", "num_envs", "grad_updates_per_step", "batch_size",
                     "episode_length", "epoch_steps", "num_eval_envs"):
            if getattr(self, name) < 1:
                raise ValueError(f"SACConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.epoch_steps % self.num_envs:
            raise ValueError(f"SACConfig.epoch_steps ({self.epoch_steps}) must be a multiple of "
                             f"num_envs ({self.num_envs})")
        if self.min_replay_size >= self.num_timesteps:
            raise ValueError("SACConfig.min_replay_size must be below num_timesteps")

    @property
    def actor_steps_per_epoch(self) -> int:
        return self.epoch_steps // self.num_envs

    @property
    def num_epochs(self) -> int:
        return -(-self.num_timesteps // self.epoch_steps)


@flax.struct.dataclass
class PolicyParams:
    """What the deterministic expert needs: observation statistics and the policy MLP."""

    normalizer: running_statistics.RunningStatisticsState
    network: Any


@flax.struct.dataclass
class TrainState:
    """Everything a resumed run needs, as one pytree of arrays."""

    policy: PolicyParams
    policy_opt: optax.OptState
    q_params: Any
    q_opt: optax.OptState
    target_q_params: Any
    log_alpha: jax.Array
    alpha_opt: optax.OptState
    buffer: replay_buffers.ReplayBufferState
    key: jax.Array
    env_steps: jax.Array      # int32 []
    grad_steps: jax.Array     # int32 []


class Trainer(NamedTuple):
    """Pure functions of one training setup (see the module docstring)."""

    init: Callable[[jax.Array], TrainState]
    prefill: Callable[[TrainState], TrainState]
    epoch: Callable[[TrainState], tuple[TrainState, dict]]
    evaluate: Callable[[PolicyParams], tuple[float, float]]
    policy_spec: Callable[[PolicyParams], dict]


def make_trainer(env: brax_envs.Env, cfg: SACConfig) -> Trainer:
    """Builds the SAC functions for Brax environment `env` (unwrapped, full observation)."""
    train_env = brax_envs.training.wrap(env, episode_length=cfg.episode_length)
    obs_size, action_size = env.observation_size, env.action_size
    networks = sac_networks.make_sac_networks(
        obs_size, action_size, preprocess_observations_fn=running_statistics.normalize,
        hidden_layer_sizes=cfg.hidden_layer_sizes)
    make_policy = sac_networks.make_inference_fn(networks)
    policy_opt = optax.adam(cfg.learning_rate)
    q_opt = optax.adam(cfg.learning_rate)
    alpha_opt = optax.adam(3e-4)
    alpha_loss, critic_loss, actor_loss = sac_losses.make_losses(
        networks, reward_scaling=cfg.reward_scaling, discounting=cfg.discounting, action_size=action_size)
    alpha_update = gradients.gradient_update_fn(alpha_loss, alpha_opt, pmap_axis_name=None)
    critic_update = gradients.gradient_update_fn(critic_loss, q_opt, pmap_axis_name=None)
    actor_update = gradients.gradient_update_fn(actor_loss, policy_opt, pmap_axis_name=None)

    dummy_obs = jnp.zeros((obs_size,))
    buffer = replay_buffers.UniformSamplingQueue(
        max_replay_size=cfg.num_timesteps + cfg.num_envs,  # never full, so never rolled
        dummy_data_sample=Transition(
            observation=dummy_obs, action=jnp.zeros((action_size,)), reward=0.0, discount=0.0,
            next_observation=dummy_obs, extras={"state_extras": {"truncation": 0.0}, "policy_extras": {}}),
        sample_batch_size=cfg.batch_size * cfg.grad_updates_per_step)

    def init(key):
        key_policy, key_q, key_buffer, key_run = jax.random.split(key, 4)
        policy_params = networks.policy_network.init(key_policy)
        q_params = networks.q_network.init(key_q)
        log_alpha = jnp.zeros((), jnp.float32)
        normalizer = running_statistics.init_state(specs.Array((obs_size,), jnp.dtype("float32")))
        return TrainState(
            policy=PolicyParams(normalizer, policy_params), policy_opt=policy_opt.init(policy_params),
            q_params=q_params, q_opt=q_opt.init(q_params), target_q_params=q_params,
            log_alpha=log_alpha, alpha_opt=alpha_opt.init(log_alpha),
            buffer=buffer.init(key_buffer), key=key_run,
            env_steps=jnp.zeros((), jnp.int32), grad_steps=jnp.zeros((), jnp.int32))

    def act(state: TrainState, env_state, key):
        policy = make_policy((state.policy.normalizer, state.policy.network))
        env_state, transitions = acting.actor_step(train_env, env_state, policy, key, extra_fields=("truncation",))
        normalizer = running_statistics.update(state.policy.normalizer, transitions.observation)
        state = state.replace(policy=state.policy.replace(normalizer=normalizer),
                              buffer=buffer.insert(state.buffer, transitions),
                              env_steps=state.env_steps + cfg.num_envs)
        return state, env_state

    def sgd_step(carry, transitions):
        state, key = carry
        key, key_alpha, key_critic, key_actor = jax.random.split(key, 4)
        norm, pol = state.policy.normalizer, state.policy.network
        a_loss, log_alpha, a_opt = alpha_update(
            state.log_alpha, pol, norm, transitions, key_alpha, optimizer_state=state.alpha_opt)
        alpha = jnp.exp(log_alpha)
        c_loss, q_params, c_opt = critic_update(
            state.q_params, pol, norm, state.target_q_params, alpha, transitions, key_critic,
            optimizer_state=state.q_opt)
        p_loss, pol, p_opt = actor_update(
            pol, norm, q_params, alpha, transitions, key_actor, optimizer_state=state.policy_opt)
        target = jax.tree.map(lambda t, q: (1 - cfg.tau) * t + cfg.tau * q, state.target_q_params, q_params)
        state = state.replace(
            policy=state.policy.replace(network=pol), policy_opt=p_opt, q_params=q_params, q_opt=c_opt,
            target_q_params=target, log_alpha=log_alpha, alpha_opt=a_opt, grad_steps=state.grad_steps + 1)
        return (state, key), {"alpha_loss": a_loss, "critic_loss": c_loss, "actor_loss": p_loss, "alpha": alpha}

    def train_step(carry, _):
        state, env_state = carry
        key_act, key_sgd, key_next = jax.random.split(state.key, 3)
        state, env_state = act(state.replace(key=key_next), env_state, key_act)
        buffer_state, transitions = buffer.sample(state.buffer)
        transitions = jax.tree.map(
            lambda x: x.reshape((cfg.grad_updates_per_step, cfg.batch_size) + x.shape[1:]), transitions)
        (state, _), metrics = jax.lax.scan(sgd_step, (state.replace(buffer=buffer_state), key_sgd), transitions)
        return (state, env_state), jax.tree.map(jnp.mean, metrics)

    def reset_envs(state: TrainState):
        key_reset, key_next = jax.random.split(state.key)
        return state.replace(key=key_next), train_env.reset(jax.random.split(key_reset, cfg.num_envs))

    # The environments live only inside one jitted call: a resumed run resets them.
    @jax.jit
    def prefill(state):
        state, env_state = reset_envs(state)

        def body(carry, _):
            st, es = carry
            key_act, key_next = jax.random.split(st.key)
            return act(st.replace(key=key_next), es, key_act), None

        n = -(-cfg.min_replay_size // cfg.num_envs)
        (state, _), _ = jax.lax.scan(body, (state, env_state), None, length=n)
        return state

    @functools.partial(jax.jit, donate_argnums=0)
    def epoch(state):
        state, env_state = reset_envs(state)
        (state, _), metrics = jax.lax.scan(train_step, (state, env_state), None, length=cfg.actor_steps_per_epoch)
        return state, jax.tree.map(jnp.mean, metrics)

    evaluator = acting.Evaluator(
        brax_envs.training.wrap(env, episode_length=cfg.episode_length),
        functools.partial(make_policy, deterministic=True), num_eval_envs=cfg.num_eval_envs,
        episode_length=cfg.episode_length, action_repeat=1, key=jax.random.PRNGKey(cfg.seed + 1))

    def evaluate(policy: PolicyParams) -> tuple[float, float]:
        m = evaluator.run_evaluation((policy.normalizer, policy.network), training_metrics={})
        return float(m["eval/episode_reward"]), float(m["eval/episode_reward_std"])

    def policy_spec(policy: PolicyParams) -> dict:
        layers = policy.network["params"]
        names = sorted(layers, key=lambda s: int(s.rsplit("_", 1)[1]))
        return {
            "obs_mean": jnp.asarray(policy.normalizer.mean, jnp.float32),
            "obs_std": jnp.asarray(policy.normalizer.std, jnp.float32),
            "kernels": [jnp.asarray(layers[n]["kernel"], jnp.float32) for n in names],
            "biases": [jnp.asarray(layers[n]["bias"], jnp.float32) for n in names],
        }

    return Trainer(init=jax.jit(init), prefill=prefill, epoch=epoch, evaluate=evaluate, policy_spec=policy_spec)


def run_epoch(trainer: Trainer, state: TrainState, best: PolicyParams, meta: dict):
    """One epoch of training, an evaluation, and the bookkeeping of the best policy.

    Returns:
      `(state, best, meta)`: `meta` gains a `history` entry and, when the
      evaluation return is the best so far, new `best_return` / `best_step`.
    """
    import time

    t0 = time.perf_counter()
    state, metrics = trainer.epoch(state)
    ret, ret_std = trainer.evaluate(state.policy)
    meta = dict(meta, wall_s=meta["wall_s"] + time.perf_counter() - t0)
    step = int(state.env_steps)
    if ret > meta["best_return"]:  # a copy: the next epoch donates (deletes) the state's buffers
        best, meta["best_return"], meta["best_step"] = jax.tree.map(jnp.copy, state.policy), ret, step
    meta["history"] = [*meta["history"], {"env_steps": step, "return": ret, "return_std": ret_std,
                                          "wall_s": meta["wall_s"], **{k: float(v) for k, v in metrics.items()}}]
    return state, best, meta


class Checkpoints:
    """The latest `(state, best policy, meta)` of a run, kept with orbax in `directory`.

    `meta` is JSON (config, best return, history, wall time); a restore refuses
    a checkpoint whose config differs from the trainer's.
    """

    def __init__(self, directory, trainer: Trainer, cfg: SACConfig):
        import pathlib

        import orbax.checkpoint as ocp

        self._ocp = ocp
        self.directory = pathlib.Path(directory).absolute()
        self.config = json.loads(json.dumps(dataclasses.asdict(cfg)))
        self._abstract = jax.eval_shape(lambda k: (lambda s: (s, s.policy))(trainer.init(k)),
                                        jax.random.PRNGKey(0))
        self._mgr = ocp.CheckpointManager(self.directory, options=ocp.CheckpointManagerOptions(
            max_to_keep=1, enable_async_checkpointing=False))

    def new_meta(self) -> dict:
        return {"config": self.config, "best_return": float("-inf"), "best_step": 0, "history": [], "wall_s": 0.0}

    def clear(self) -> None:
        for step in self._mgr.all_steps():
            self._mgr.delete(step)

    def restore(self):
        """`(state, best, meta)` of the latest checkpoint, or None if there is none.

        Raises:
          ValueError: the checkpoint was written with another config, or is
            corrupt or incomplete (one line; the files are left as they are).
        """
        step = self._mgr.latest_step()
        if step is None:
            return None
        ocp = self._ocp
        try:
            restored = self._mgr.restore(step, args=ocp.args.Composite(
                state=ocp.args.StandardRestore(self._abstract), meta=ocp.args.JsonRestore()))
            (state, best), meta = restored["state"], restored["meta"]
        except Exception as e:  # orbax and tensorstore raise many kinds; all mean "cannot be read"
            why = " ".join(f"{type(e).__name__}: {e}".split())
            raise ValueError(f"{self.directory / str(step)}: corrupt or incomplete checkpoint ({why[:300]})") from e
        if not isinstance(meta, dict) or not isinstance(meta.get("config"), dict):
            raise ValueError(f"{self.directory / str(step)}: corrupt checkpoint (its meta has no config)")
        if meta["config"] != self.config:
            raise ValueError(f"{self.directory} holds a run with other settings ({meta['config']})")
        return state, best, meta

    def save(self, state: TrainState, best: PolicyParams, meta: dict) -> None:
        ocp = self._ocp
        self._mgr.save(int(state.env_steps), args=ocp.args.Composite(
            state=ocp.args.StandardSave((state, best)), meta=ocp.args.JsonSave(meta)))

    def close(self) -> None:
        self._mgr.close()
