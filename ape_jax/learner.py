"""The weighted behavioural-cloning learner, pure-functional: one config, or a whole grid × seeds, in one program.

    learner = make_train(LearnerConfig(obs_shape=(5,), action_dim=3, iterations=20_000))
    params, metrics = learner.train(key, hparams, data)                     # one policy
    params, metrics = jax.jit(jax.vmap(learner.train, (0, 0, None)))(keys, grid, data)  # the grid

`LearnerConfig` holds shapes and counts (static); `Hparams` holds the traced
knobs (the `Weighting` and the learning rate), so a grid is a `vmap`. The loop is
a `lax.scan`; for progress bars, `init` + `run(state, ..., n)` train in chunks.

Per minibatch (uniform sampling with replacement) the loss is
`mean_i(w_i · ℓ_i)` with `ℓ` the squared error summed over action dimensions
(`"l2"`, MuJoCo) or the absolute error (`"l1"`, ToyCar), and `w` from
`ape_jax.weighting` (stop-gradient). The policy sees the last `H` observations,
padded at episode starts by repeating the first one. Adam with learning rate
`lr · 0.1^⌊step / lr_decay_every⌋`.

HistoryDropout (Bansal et al., 2018) is a traced knob of the same learner:
with `Hparams.history_dropout = p > 0` each *past* observation of a training
history (not the current one) is replaced by zeros with probability p,
independently per sample and frame (for standardised states zero is the
training mean; for images a black frame); evaluation sees the full history.

Every learner of the project (this one and the baselines' in
`ape_jax.baselines`) is a `Learner`: `init`, `run` in chunks, and for methods
that train in rounds (boosting, DAgger) `next_round` between rounds of
`round_iterations`; `policy_params(state)` gives parameters of `cfg.model()`,
so evaluation and the loss analysis treat every method alike.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from ape_jax import weighting
from ape_jax.history import history_index
from ape_jax.models import IMAGE_ENCODERS, StatePolicy
from ape_jax.weighting import Weighting

LOSSES = ("l2", "l1")


@dataclasses.dataclass(frozen=True)
class LearnerConfig:
    """Static settings: shapes and counts (changing one recompiles)."""

    obs_shape: tuple[int, ...]   # one observation: (D,) for states, (height, width, 3) for images
    action_dim: int
    history: int = 2             # H: 1 for BC-SO
    iterations: int = 300_000
    batch_size: int = 128
    lr_decay_every: int = 100_000
    loss: str = "l2"
    unroll: bool = False         # unroll `run`'s scan: XLA:CPU runs convolutions in loop bodies ~50x slower
    # Image encoder: "small" (`ImagePolicy`, 3 convs, CPU-sized) or "resnet18" (`ResNet18Policy`, the
    # supplement's MuJoCo-Image network, ~11M parameters: for GPUs). State observations always use
    # `StatePolicy`; they accept only "small", so a config never records an encoder it did not use.
    encoder: str = "small"

    def __post_init__(self):
        if self.loss not in LOSSES:
            raise ValueError(f"unknown loss {self.loss!r}; valid: {list(LOSSES)}")
        if len(self.obs_shape) not in (1, 3):
            raise ValueError(f"obs_shape must be (D,) or (height, width, channels), got {self.obs_shape}")
        if self.encoder not in IMAGE_ENCODERS:
            raise ValueError(f"unknown encoder {self.encoder!r}; valid: {list(IMAGE_ENCODERS)}")
        if self.encoder != "small" and not self.images:
            raise ValueError(f"encoder {self.encoder!r} is for image observations; state observations "
                             f"(obs_shape {self.obs_shape}) use the MLP StatePolicy: leave encoder='small'")
        for name in ("action_dim", "history", "iterations", "batch_size", "lr_decay_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"LearnerConfig.{name} must be >= 1, got {getattr(self, name)}")

    @property
    def images(self) -> bool:
        return len(self.obs_shape) == 3

    def model(self) -> nn.Module:
        return IMAGE_ENCODERS[self.encoder](self.action_dim) if self.images else StatePolicy(self.action_dim)


@struct.dataclass
class Hparams:
    """Traced knobs of one configuration (stack them along a leading axis for a grid)."""

    weighting: Weighting
    lr: jax.Array               # [] float32
    history_dropout: jax.Array  # [] float32, probability of zeroing each past observation

    @classmethod
    def make(cls, kind: str = "uniform", lr: float = 2e-4, history_dropout: float = 0.0,
             **weighting_kw) -> "Hparams":
        if not 0.0 <= history_dropout < 1.0:
            raise ValueError(f"history dropout must be in [0, 1), got {history_dropout}")
        if not lr > 0.0:
            raise ValueError(f"learning rate must be > 0, got {lr}")
        return cls(Weighting.make(kind, **weighting_kw), jnp.float32(lr), jnp.float32(history_dropout))


@struct.dataclass
class Data:
    """A training split on device; observations already standardised (states) or uint8 (images).

    obs `[N, *obs_shape]`, action `[N, A] float32`, t `[N] int32`, ape `[N] float32`;
    `scores` `[S, N] float32` is the table the weightings read (`None`: just the APE).
    """

    obs: jax.Array
    action: jax.Array
    t: jax.Array
    ape: jax.Array
    scores: jax.Array | None = None

    def score_table(self) -> jax.Array:
        return self.ape[None] if self.scores is None else self.scores


@struct.dataclass
class TrainState:
    params: Any
    opt_state: Any
    step: jax.Array           # [] int32
    key: jax.Array
    static_weights: jax.Array  # [N] the weighting's dataset-level weights


class Learner(NamedTuple):
    """The pure functions of one learner (see the module docstring); `state` and `hp` are the learner's own."""

    init: Callable[[jax.Array, Any, Data], Any]
    run: Callable[[Any, Any, Data, int], tuple[Any, dict]]  # n iterations; metrics [n] incl. "loss"
    train: Callable[[jax.Array, Any, Data], tuple[Any, dict]]  # everything; -> (policy params, metrics)
    policy_input: Callable[[jax.Array], jax.Array]
    per_sample_loss: Callable[[Any, Data, jax.Array], jax.Array]  # (policy params, data, idx) -> [B]
    policy_params: Callable[[Any], Any] = lambda state: state.params
    rounds: int = 1
    round_iterations: int = 0  # iterations per round; total = rounds * round_iterations
    next_round: Callable[[Any, Any, Data], Any] | None = None  # between rounds


def train_in_rounds(learner: Learner, key: jax.Array, hp: Any, data: Data) -> tuple[Any, dict]:
    """`init`, then each round's `run` with `next_round` between rounds: a `Learner.train` for round-based methods."""
    state, metrics = learner.init(key, hp, data), []
    for r in range(learner.rounds):
        if r:
            state = learner.next_round(state, hp, data)
        state, m = learner.run(state, hp, data, learner.round_iterations)
        metrics.append(m)
    return learner.policy_params(state), jax.tree.map(lambda *xs: jnp.concatenate(xs), *metrics)


def stack_hparams(configs: list[Hparams]) -> Hparams:
    return jax.tree.map(lambda *xs: jnp.stack(xs), *configs)


def drop_history(key: jax.Array, history: jax.Array, p: jax.Array | float) -> jax.Array:
    """HistoryDropout: each past observation of `history [B, H, ...]` zeroed with probability `p`.

    The current (last) observation is always kept; draws are independent per
    sample and frame. `p = 0` returns `history` unchanged.
    """
    keep = jax.random.uniform(key, history.shape[:2]) >= p
    keep = keep.at[:, -1].set(True)
    return jnp.where(keep.reshape(keep.shape + (1,) * (history.ndim - 2)), history, jnp.zeros((), history.dtype))


def dataset_losses(learner: Learner, params: Any, data: Data, chunk: int | None = None) -> jax.Array:
    """`[N]` unweighted loss of every sample of `data` under policy `params`, `chunk` rows at a time.

    The chunks run in a `lax.map`, so memory holds one chunk's activations
    whatever `N` is, and the program's size does not grow with `N`. Default
    chunk: 256 frames for images (a CNN's activations are large), 4,096 rows
    of states.
    """
    n = data.obs.shape[0]
    chunk = chunk or (256 if data.obs.ndim >= 4 else 4096)
    chunk = max(1, min(chunk, n))
    rounds = -(-n // chunk)
    idx = jnp.arange(rounds * chunk).reshape(rounds, chunk) % n  # the last chunk wraps around; cut off below
    losses = jax.lax.map(lambda i: learner.per_sample_loss(params, data, i), idx)
    return losses.reshape(-1)[:n]


def learning_rate(cfg: LearnerConfig, lr: jax.Array, step: jax.Array) -> jax.Array:
    """The schedule every learner uses: `lr · 0.1^⌊step / cfg.lr_decay_every⌋` (traced `lr` and `step`)."""
    return lr * 0.1 ** (step // cfg.lr_decay_every).astype(jnp.float32)


def adam_step(adam: optax.GradientTransformation, params: Any, grads: Any, opt_state: Any, lr: jax.Array
              ) -> tuple[Any, Any]:
    """One step of a `scale_by_adam` transform with the learning rate applied by hand (so it can be traced)."""
    updates, opt_state = adam.update(grads, opt_state)
    return jax.tree.map(lambda p, u: p - lr * u, params, updates), opt_state


def make_train(cfg: LearnerConfig) -> Learner:
    """The pure functions of one learner setup (see the module docstring)."""
    model = cfg.model()
    adam = optax.scale_by_adam()

    def policy_input(history_obs: jax.Array) -> jax.Array:
        """`[..., H, *obs_shape]` -> the model's input (flattened states, or frames on channels in [0, 1])."""
        if not cfg.images:
            return history_obs.reshape(history_obs.shape[:-2] + (-1,)).astype(jnp.float32)
        x = jnp.moveaxis(history_obs, -4, -2)  # [..., h, w, H, 3]
        return x.reshape(x.shape[:-2] + (-1,)).astype(jnp.float32) / 255.0

    def batch(data: Data, idx: jax.Array, dropout_key: jax.Array | None = None, dropout=0.0) -> jax.Array:
        obs = data.obs[history_index(data.t, idx, cfg.history)]  # [B, H, *obs_shape]
        if dropout_key is not None:
            obs = drop_history(dropout_key, obs, dropout)
        return policy_input(obs)

    def per_sample_loss(params, data: Data, idx: jax.Array, dropout_key=None, dropout=0.0) -> jax.Array:
        err = model.apply(params, batch(data, idx, dropout_key, dropout)) - data.action[idx]
        return jnp.sum(err**2 if cfg.loss == "l2" else jnp.abs(err), axis=-1)

    def init(key: jax.Array, hp: Hparams, data: Data) -> TrainState:
        if data.obs.shape[0] < cfg.batch_size:
            raise ValueError(f"the training set has {data.obs.shape[0]} samples, fewer than the batch size "
                             f"{cfg.batch_size}")
        key_init, key_run = jax.random.split(key)
        dummy = policy_input(jnp.zeros((1, cfg.history, *cfg.obs_shape), data.obs.dtype))
        params = model.init(key_init, dummy)
        return TrainState(params=params, opt_state=adam.init(params), step=jnp.zeros((), jnp.int32),
                          key=key_run, static_weights=weighting.dataset_weights(data.score_table(), hp.weighting))

    def update(state: TrainState, hp: Hparams, data: Data):
        key_step = jax.random.fold_in(state.key, state.step)
        idx = jax.random.randint(key_step, (cfg.batch_size,), 0, data.obs.shape[0])
        key_drop = jax.random.fold_in(key_step, 1)
        w = weighting.batch_weights(data.score_table(), state.static_weights, idx, hp.weighting)

        def loss_fn(params):
            ell = per_sample_loss(params, data, idx, key_drop, hp.history_dropout)
            return jnp.mean(w * ell), jnp.mean(ell)

        (weighted, unweighted), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params)
        params, opt_state = adam_step(adam, state.params, grads, state.opt_state,
                                      learning_rate(cfg, hp.lr, state.step))
        state = state.replace(params=params, opt_state=opt_state, step=state.step + 1)
        return state, {"loss": weighted, "unweighted_loss": unweighted}

    def run(state: TrainState, hp: Hparams, data: Data, n: int):
        if n == 1 and cfg.unroll:  # a one-trip scan stays a loop even unrolled: the slow path `unroll` avoids
            state, metrics = update(state, hp, data)
            return state, jax.tree.map(lambda x: x[None], metrics)
        return jax.lax.scan(lambda s, _: update(s, hp, data), state, None, length=n, unroll=cfg.unroll)

    def train(key: jax.Array, hp: Hparams, data: Data):
        state, metrics = run(init(key, hp, data), hp, data, cfg.iterations)
        return state.params, metrics

    return Learner(init=init, run=run, train=train, policy_input=policy_input, per_sample_loss=per_sample_loss,
                   round_iterations=cfg.iterations)
