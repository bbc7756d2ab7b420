"""ActionChunks: ACT's action chunking with temporal ensembling (Zhao, Kumar, Levine and Finn, RSS 2023, "Learning
Fine-Grained Bimanual Manipulation with Low-Cost Hardware", Sec. IV, "Action Chunking and Temporal Ensemble"), on the
project's network: the history-free competitor of the copycat methods.

**Training** (action chunking). The policy sees the current observation only (history 1, BC-SO's input) and
predicts the next `k` actions at once, `π(o_t) = (â_t, …, â_{t+k−1})`: the network is `cfg.model()` with `k · A`
outputs, read as `[k, A]`. The loss is the project's per-action loss averaged over the chunk,

    L = mean_i (1/k) Σ_{j<k} ℓ(â_{t+j}, a_{t+j}),

`ℓ` squared error summed over action dimensions (absolute error for L1 tasks, with their weights). Targets past an
episode's end repeat its last action (`ape_jax.history.future_index`), and count in the loss; ACT pads them with
zeros and leaves them out of its loss (`is_pad` in its `utils.py` and `policy.py`).

**Acting** (temporal ensemble). Every step queries the policy; the action executed at `t` is the weighted mean of
every prediction for `t` (the chunks made at `t − k + 1, …, t`; fewer at an episode's start),

    a_t = Σ_i w_i â_t^{(i)} / Σ_i w_i,   w_i = exp(−m · i),

`i = 0` the OLDEST prediction, as ACT says ("w_0 is the weight for the oldest action") and its code does
(`imitate_episodes.py`: `all_time_actions[:, t]`, rows by query time, weighted `exp(−k · arange(n))`). So `m > 0`
leans on the older predictions, `m = 0` averages them alike, and a larger `m` lets new observations in more slowly.
`temporal_ensemble` computes it from a buffer of the last `k` chunks (`ensemble_policy`, the run-time policy the
evaluation, the videos and the copycat diagnostics' rollouts use: `policy_runtime`, `ape_jax.evaluate.Runtime`).
The mean is taken in the actions' units and then clipped to the action bounds; ACT averages standardised actions and
un-standardises after, an affine map, so the mean is the same.

Knobs (`ChunkKnobs`, `--set action-chunks.KNOB=VALUE`): `k` (static: the network's width), default 100, ACT's chunk
size (`--chunk_size 100` in its README's commands and its hyperparameters); `m`, default 0.01, ACT's ensemble weight
(`imitate_episodes.py`: `k = 0.01`). Both are recorded in each run's `hparams` (`{"k": 100.0, "m": 0.01}`), which
is where evaluation reads them. **Neutral:** `k = 1` is BC-SO: the same network (`A` outputs), initialisation,
minibatches (`make_train`'s draws) and loss, and the ensemble of one prediction is that prediction (tested).

Our readings:

- **The network** is the recipe's policy (`StatePolicy`, or the recipe's image encoder) with a wider output layer,
  trained with the project's loss; ACT is a conditional VAE of transformers trained with an L1 loss and a KL term
  (weight 10). The experts here are deterministic, so the style variable has nothing to model.
- **The loss analysis** and **the copycat probe** read the chunk's first action (the prediction for `t`) and the
  Head's embedding, as BC-SO's; the own-rollout predictability reads the ensembled actions the environment ran.
- **k and the episode**: at `k = 100` a chunk spans a fifth of a `fca`-protocol episode (500 steps) and a tenth of
  a Brax one; ACT's 100 steps are 2 s at 50 Hz. The default is the authors' number, not one tuned here.

Metrics (`[n]` float32 per `run` of `n` iterations): `"loss"` and `"unweighted_loss"` (the chunk's loss `L`),
`"first_loss"` (the loss of `â_t` alone, BC-SO's).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

import envs
from ape_jax import methods
from ape_jax.evaluate import Runtime
from ape_jax.history import future_index, history_index
from ape_jax.knobs import integer, nonnegative, positive
from ape_jax.learner import (Data, Learner, LearnerConfig, action_errors, augment, gradient_step, learning_rate,
                             make_train, policy_apply, scanned_learner, trainable)

NAME = "action-chunks"
DEFAULT_K = 100         # ACT's chunk size: its README's `--chunk_size 100`
DEFAULT_M = 0.01        # ACT's temporal ensemble weight: imitate_episodes.py, `k = 0.01`


@dataclasses.dataclass(frozen=True)
class ChunkKnobs:
    """ActionChunks' own settings (`--set action-chunks.KNOB=VALUE`; the module docstring).

    Attributes:
      k: the actions each query predicts, `a_t … a_{t+k−1}` (static: the output layer's width); 1 is BC-SO.
      m: the temporal ensemble's weight, `w_i = exp(−m · i)` with `i = 0` the oldest prediction; >= 0.
    """

    k: int = DEFAULT_K
    m: float = DEFAULT_M

    def __post_init__(self):
        integer(f"{NAME}.k", self.k, 1)
        nonnegative(f"{NAME}.m", self.m)


@struct.dataclass
class ChunkHparams:
    """Traced knobs of one ActionChunks run (stack them along a leading axis for seeds): the learning rate. `k` is
    static (the learner's) and `m` acts at evaluation only (`policy_runtime`)."""

    lr: jax.Array   # [] float32

    @classmethod
    def make(cls, lr: float = 2e-4) -> ChunkHparams:
        """Validated hyperparameters (`ValueError`, one line, for a value out of range)."""
        positive("learning rate", lr)
        return cls(lr=jnp.float32(lr))


@struct.dataclass
class ChunkState:
    """The scan carry: BC-SO's (policy variables, Adam moments, step, key), its network `k · A` wide."""

    params: Any              # chunk_config(cfg, k).model() variables
    opt_state: Any           # on trainable(params)
    step: jax.Array          # [] int32
    key: jax.Array


def chunk_config(cfg: LearnerConfig, k: int) -> LearnerConfig:
    """The chunk network's config: `cfg` with `k · A` outputs (its `model()` is the policy trained and evaluated).
    The per-dimension loss weights stay `cfg`'s: the loss reads the outputs as `k` actions of `A`."""
    return dataclasses.replace(cfg, action_dim=k * cfg.action_dim, loss_weights=())


def make_action_chunks(cfg: LearnerConfig, k: int = DEFAULT_K) -> Learner:
    """The pure functions of ActionChunks for one static setup (the module docstring).

    Args:
      cfg: shapes, counts and the recipe, `cfg.action_dim` = A (the program's; history 1 for the method).
      k: the chunk's length (>= 1).

    Returns:
      A `Learner` whose `init` and minibatches are `make_train(cfg)`'s (the same key gives BC-SO's initialisation
      and rows), policy parameters those of `chunk_config(cfg, k).model()`.
    """
    ChunkKnobs(k=k)   # the one rule for k
    net_cfg = chunk_config(cfg, k)
    base, model, adam = make_train(net_cfg), net_cfg.model(), cfg.optimizer()
    a = cfg.action_dim

    def init(key: jax.Array, hp: ChunkHparams, data: Data) -> ChunkState:
        key_init, key_run = jax.random.split(key)   # as make_train: the same policy and batches for the same key
        params = base.init_policy(key_init, data)
        return ChunkState(params=params, opt_state=adam.init(trainable(params)), step=jnp.zeros((), jnp.int32),
                          key=key_run)

    def update(state: ChunkState, hp: ChunkHparams, data: Data):
        key_step = jax.random.fold_in(state.key, state.step)
        _, idx = data.sample(key_step, cfg.batch_size)   # make_train's rows and augmentation key
        x = base.policy_input(augment(cfg, jax.random.fold_in(key_step, 2),
                                      data.obs[history_index(data.t, idx, cfg.history)]))
        target = data.action[future_index(data.t, idx, k)]   # [B, k, A]

        def loss_fn(variables):
            predicted, variables = policy_apply(model, variables, x, train=True)
            ell = action_errors(cfg, predicted.reshape(predicted.shape[:-1] + (k, a)), target)   # [B, k]
            return jnp.mean(ell), (jnp.mean(ell[:, 0]), variables)

        params, opt_state, loss, first = gradient_step(
            adam, state.params, state.opt_state, learning_rate(cfg, hp.lr, state.step), loss_fn)
        state = state.replace(params=params, opt_state=opt_state, step=state.step + 1)
        return state, {"loss": loss, "unweighted_loss": loss, "first_loss": first}

    learner = scanned_learner(net_cfg, base, init, update)
    return learner._replace(per_sample_loss=_first_action_loss(cfg, k))


def _first_action_loss(cfg: LearnerConfig, k: int):
    """`(params, data, idx) -> [B]`: the loss of each row's predicted `a_t` (the chunk's first action)."""
    apply, learner = first_action(cfg, k), make_train(cfg)

    def per_sample_loss(params, data: Data, idx: jax.Array) -> jax.Array:
        x = learner.policy_input(data.obs[history_index(data.t, idx, cfg.history)])
        return action_errors(cfg, apply(params, x), data.action[idx])

    return per_sample_loss


def first_action(cfg: LearnerConfig, k: int):
    """The chunk network read as a policy of `t`: `apply(variables, x, return_embedding=False)` -> `â_t` `[..., A]`
    (and the Head's embedding), as `cfg.model().apply` reads BC-SO's."""
    model, a = chunk_config(cfg, k).model(), cfg.action_dim

    def apply(variables: Any, x: jax.Array, return_embedding: bool = False):
        out = model.apply(variables, x, return_embedding=return_embedding)
        return (out[0][..., :a], out[1]) if return_embedding else out[..., :a]

    return apply


def temporal_ensemble(chunks: jax.Array, made: jax.Array, m: jax.Array | float) -> jax.Array:
    """The action for the current step from the last `k` chunks (ACT's temporal ensemble, the module docstring).

    Args:
      chunks: `[k, k, A] float32`, the chunks queried at the last `k` steps, oldest first: row `r` was queried
        `k − 1 − r` steps ago, so its entry `k − 1 − r` predicts the current step.
      made: `[k] bool`, whether row `r` was queried in this episode (the last `n` rows, `n` the steps so far).
      m: the ensemble weight, >= 0.

    Returns:
      `[A] float32`: `Σ_i w_i â^{(i)} / Σ_i w_i` over the rows made, `w_i = exp(−m · i)`, `i = 0` the oldest.
    """
    k = chunks.shape[0]
    rows = jnp.arange(k)
    predictions = chunks[rows, k - 1 - rows]                       # [k, A]
    age = rows - (k - jnp.sum(made.astype(jnp.int32)))             # 0 for the oldest row made
    w = jnp.where(made, jnp.exp(-m * jnp.maximum(age, 0).astype(jnp.float32)), 0.0)
    return jnp.sum(w[:, None] * predictions, axis=0) / jnp.sum(w)


class EnsembleCarry(NamedTuple):
    """The run-time policy's carry."""

    history: jax.Array   # [H, *obs_shape], the standardised observations (H = 1 for the method)
    chunks: jax.Array    # [k, k, A], the last k chunks, oldest first
    made: jax.Array      # [k] bool


def ensemble_policy(cfg: LearnerConfig, k: int, m: float, obs_mean: jax.Array | None, obs_std: jax.Array | None,
                    env: envs.Env) -> envs.Policy:
    """The trained chunk network as an `envs.Policy` that queries it every step and executes the temporal ensemble
    of every chunk's prediction for that step (`temporal_ensemble`), clipped to `env.action_bounds`. Observations
    are standardised and the history padded as `ape_jax.evaluate.history_policy` does; an episode starts with no
    chunk made."""
    model, learner, a = chunk_config(cfg, k).model(), make_train(cfg), cfg.action_dim
    low, high = env.action_bounds

    def observe(state):
        return state.obs if obs_mean is None else (state.obs - obs_mean) / obs_std

    def init(params, state) -> EnsembleCarry:
        return EnsembleCarry(history=jnp.repeat(observe(state)[None], cfg.history, axis=0),
                             chunks=jnp.zeros((k, k, a), jnp.float32), made=jnp.zeros((k,), bool))

    def act(params, carry: EnsembleCarry, state, key):
        history = jnp.concatenate([carry.history[1:], observe(state)[None]])
        chunk = model.apply(params, learner.policy_input(history[None]))[0].reshape(k, a)
        chunks = jnp.concatenate([carry.chunks[1:], chunk[None].astype(jnp.float32)])
        made = jnp.concatenate([carry.made[1:], jnp.ones((1,), bool)])
        action = temporal_ensemble(chunks, made, m)
        return jnp.clip(action, low, high), EnsembleCarry(history, chunks, made)

    return envs.Policy(init=init, act=act)


def policy_runtime(cfg: LearnerConfig, settings: Sequence[Mapping[str, float]]) -> Runtime:
    """How evaluation reads ActionChunks' policies (its `Method.runtime`): the chunk's first action and
    the Head's embedding (`first_action`), and the temporal ensemble at run time (`ensemble_policy`), with the `k`
    and `m` each run recorded (one group's runs share them: one sweep's knobs)."""
    chosen = {(float(s["k"]), float(s["m"])) for s in settings}
    if len(chosen) != 1:
        raise ValueError(f"{NAME}: one group's policies must share k and m, got {sorted(chosen)}")
    (k, m), = chosen
    k = int(k) if k.is_integer() else k
    ChunkKnobs(k=k, m=m)   # the one rule for both
    return Runtime(apply=first_action(cfg, k), policy=functools.partial(ensemble_policy, cfg, k, m))


def _grid(ctx) -> list[dict]:
    knobs = ctx.knobs_of(NAME)
    return [{"k": float(knobs.k), "m": float(knobs.m)}]


methods.register(methods.Method(
    NAME, "ActionChunks", grid=_grid, hparams=lambda settings, lr, row: ChunkHparams.make(lr),
    program=NAME, history=1, learner=lambda ctx: make_action_chunks(ctx.cfg, ctx.knobs_of(NAME).k),
    knobs=ChunkKnobs, runtime=policy_runtime, module=__name__))
