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
from ape_jax.data import history_index
from ape_jax.models import ImagePolicy, StatePolicy
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

    def __post_init__(self):
        if self.loss not in LOSSES:
            raise ValueError(f"unknown loss {self.loss!r}; valid: {list(LOSSES)}")
        if len(self.obs_shape) not in (1, 3):
            raise ValueError(f"obs_shape must be (D,) or (height, width, channels), got {self.obs_shape}")
        for name in ("action_dim", "history", "iterations", "batch_size", "lr_decay_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"LearnerConfig.{name} must be >= 1, got {getattr(self, name)}")

    @property
    def images(self) -> bool:
        return len(self.obs_shape) == 3

    def model(self) -> nn.Module:
        return ImagePolicy(self.action_dim) if self.images else StatePolicy(self.action_dim)


@struct.dataclass
class Hparams:
    """Traced knobs of one configuration (stack them along a leading axis for a grid)."""

    weighting: Weighting
    lr: jax.Array  # [] float32

    @classmethod
    def make(cls, kind: str = "uniform", lr: float = 2e-4, **weighting_kw) -> "Hparams":
        return cls(Weighting.make(kind, **weighting_kw), jnp.float32(lr))


@struct.dataclass
class Data:
    """A training split on device; observations already standardised (states) or uint8 (images).

    obs `[N, *obs_shape]`, action `[N, A] float32`, t `[N] int32`, ape `[N] float32`.
    """

    obs: jax.Array
    action: jax.Array
    t: jax.Array
    ape: jax.Array


@struct.dataclass
class TrainState:
    params: Any
    opt_state: Any
    step: jax.Array           # [] int32
    key: jax.Array
    static_weights: jax.Array  # [N] the weighting's dataset-level weights


class Learner(NamedTuple):
    init: Callable[[jax.Array, Hparams, Data], TrainState]
    run: Callable[[TrainState, Hparams, Data, int], tuple[TrainState, dict]]
    train: Callable[[jax.Array, Hparams, Data], tuple[Any, dict]]
    policy_input: Callable[[jax.Array], jax.Array]
    per_sample_loss: Callable[[Any, Data, jax.Array], jax.Array]


def stack_hparams(configs: list[Hparams]) -> Hparams:
    return jax.tree.map(lambda *xs: jnp.stack(xs), *configs)


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

    def batch(data: Data, idx: jax.Array) -> jax.Array:
        return policy_input(data.obs[history_index(data.t, idx, cfg.history)])

    def per_sample_loss(params, data: Data, idx: jax.Array) -> jax.Array:
        err = model.apply(params, batch(data, idx)) - data.action[idx]
        return jnp.sum(err**2 if cfg.loss == "l2" else jnp.abs(err), axis=-1)

    def init(key: jax.Array, hp: Hparams, data: Data) -> TrainState:
        if data.obs.shape[0] < cfg.batch_size:
            raise ValueError(f"the training set has {data.obs.shape[0]} samples, fewer than the batch size "
                             f"{cfg.batch_size}")
        key_init, key_run = jax.random.split(key)
        dummy = policy_input(jnp.zeros((1, cfg.history, *cfg.obs_shape), data.obs.dtype))
        params = model.init(key_init, dummy)
        return TrainState(params=params, opt_state=adam.init(params), step=jnp.zeros((), jnp.int32),
                          key=key_run, static_weights=weighting.dataset_weights(data.ape, hp.weighting))

    def update(state: TrainState, hp: Hparams, data: Data):
        idx = jax.random.randint(jax.random.fold_in(state.key, state.step), (cfg.batch_size,), 0,
                                 data.obs.shape[0])
        w = weighting.batch_weights(data.ape, state.static_weights, idx, hp.weighting)

        def loss_fn(params):
            ell = per_sample_loss(params, data, idx)
            return jnp.mean(w * ell), jnp.mean(ell)

        (weighted, unweighted), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params)
        updates, opt_state = adam.update(grads, state.opt_state)
        lr = hp.lr * 0.1 ** (state.step // cfg.lr_decay_every).astype(jnp.float32)
        params = jax.tree.map(lambda p, u: p - lr * u, state.params, updates)
        state = state.replace(params=params, opt_state=opt_state, step=state.step + 1)
        return state, {"loss": weighted, "unweighted_loss": unweighted}

    def run(state: TrainState, hp: Hparams, data: Data, n: int):
        return jax.lax.scan(lambda s, _: update(s, hp, data), state, None, length=n)

    def train(key: jax.Array, hp: Hparams, data: Data):
        state, metrics = run(init(key, hp, data), hp, data, cfg.iterations)
        return state.params, metrics

    return Learner(init=init, run=run, train=train, policy_input=policy_input, per_sample_loss=per_sample_loss)
