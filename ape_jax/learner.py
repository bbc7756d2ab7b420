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
padded at episode starts by repeating the first one. Adam (β1, β2 of the
config) with learning rate `lr` × `lr_schedule(cfg)` (the paper's piecewise schedule:
×0.1 at 100k and 200k of 300k iterations; constant and cosine with warm-up too).

**Rows.** A split may be rows drawn from whole episodes (the FCA code's split):
`Data.rows` names the rows a minibatch is drawn from, while histories (and ψ's
past actions) read the whole episodes the arrays hold. Per-sample arrays
(`ape`, `scores`, the weights) are indexed by *position* in `rows`; `rows=None`
means every row.

**BatchNorm.** A policy's parameters are its Flax variables: `{"params": …}`,
plus `{"batch_stats": …}` for a network with BatchNorm (`LearnerConfig.network
= "bn-mlp"`, the FCA code's). Training applies it on batch statistics and
updates the running ones (`policy_apply(..., train=True)`); every other use
(evaluation, the loss analysis, the probes) applies it as it is, on the running
statistics. Under `vmap` every configuration keeps its own statistics.

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
import math
from typing import Any, NamedTuple
from collections.abc import Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from ape_jax import knobs, models, weighting
from ape_jax.history import history_index
from ape_jax.models import IMAGE_ENCODERS, StatePolicy
from ape_jax.weighting import Weighting



@dataclasses.dataclass(frozen=True)
class LearnerConfig:
    """Static settings: shapes and counts (changing one recompiles)."""

    obs_shape: tuple[int, ...]   # one observation: (D,) for states, (height, width, 3) for images
    action_dim: int
    history: int = 2             # H: the steps a history spans (data and rollouts keep them); 1 for BC-SO
    # the policy sees every history_stride-th of those steps, ending at the current one (`frames` of them):
    # `history - 1` must be a multiple of it (`Settings.learner_config` makes it so)
    history_stride: int = 1
    iterations: int = 300_000
    batch_size: int = 128
    lr_boundaries: tuple[int, ...] = (100_000, 200_000)  # piecewise: steps at which the learning rate drops
    lr_schedule: str = "piecewise"  # `knobs.SCHEDULES`; what `lr_schedule` builds
    lr_decay: float = 0.1        # piecewise: the factor at each boundary
    warmup_steps: int = 0        # cosine: steps the learning rate climbs from 0 to its peak
    beta1: float = 0.9           # Adam's moment decays (the FCA code: 0.5, 0.999)
    beta2: float = 0.999
    network: str = "mlp"         # state policies: "mlp", or "bn-mlp" (the FCA code's, BatchNorm in the encoder)
    init: str = "lecun"          # Dense kernels: "lecun" (Flax's default) or "xavier" (the FCA code's)
    bn_momentum: float = 0.1     # BatchNorm's running statistics: new = (1 − m) · old + m · batch (PyTorch's m)
    loss: str = "l2"
    # each action dimension's share of the loss (CILRS: steer 0.5, throttle 0.45, brake 0.05); (): each counts 1
    loss_weights: tuple[float, ...] = ()
    unroll: bool = False         # unroll `run`'s scan: XLA:CPU runs convolutions in loop bodies ~50x slower
    # Image encoder: "small" (`ImagePolicy`, 3 convs, CPU-sized), "patch" (`PatchPolicy`, one 8×8 patch
    # embedding: ~5× faster on a CPU), "drq" (`DrQPolicy`, DrQ's four 3×3 convs, 84×84) or "resnet18"
    # (`ResNet18Policy`, the supplement's MuJoCo-Image network, ~11M parameters: for GPUs). State observations
    # always use `StatePolicy`; they accept only "small", so a config never records an encoder it did not use.
    encoder: str = "small"
    # Image encoders "small", "patch" and "drq": "group" puts GroupNorm after each encoder layer (`models.encoder_norm`)
    encoder_norm: str = "none"
    # Images: each training sample's frames shifted by one random offset of up to this many pixels (`augment`)
    augment_shift: int = 0
    # The policy's arithmetic (`models.DTYPES`): "bfloat16" computes every layer in bfloat16 with float32
    # parameters, optimiser state and loss (mixed precision); refused on a backend without it (`bf16_problem`)
    dtype: str = "float32"
    # encoder "perception" (`models.PerceptionPolicy`): the SHA-256 of the pretrained encoder it starts from
    perception_sha256: str = ""

    def __post_init__(self):
        knobs.check("LearnerConfig.", network=self.network, init=self.init, encoder=self.encoder,
                    encoder_norm=self.encoder_norm, lr_schedule=self.lr_schedule, loss=self.loss, beta1=self.beta1,
                    beta2=self.beta2, bn_momentum=self.bn_momentum, lr_decay=self.lr_decay,
                    batch_size=self.batch_size, augment_shift=self.augment_shift, dtype=self.dtype)
        if self.dtype == "bfloat16" and (problem := models.bf16_problem()):
            raise ValueError(f"LearnerConfig.dtype 'bfloat16': {problem}")
        if len(self.obs_shape) not in (1, 3):
            raise ValueError(f"obs_shape must be (D,) or (height, width, channels), got {self.obs_shape}")
        if self.encoder != "small" and not self.images:
            raise ValueError(f"encoder {self.encoder!r} is for image observations; state observations "
                             f"(obs_shape {self.obs_shape}) use the MLP StatePolicy: leave encoder='small'")
        for name in ("action_dim", "history", "iterations", "history_stride"):
            if getattr(self, name) < 1:
                raise ValueError(f"LearnerConfig.{name} must be >= 1, got {getattr(self, name)}")
        if (self.history - 1) % self.history_stride:
            raise ValueError(f"LearnerConfig.history - 1 ({self.history - 1}) must be a multiple of history_stride "
                             f"({self.history_stride})")
        if self.loss_weights and (len(self.loss_weights) != self.action_dim or min(self.loss_weights) < 0):
            raise ValueError(f"LearnerConfig.loss_weights must be {self.action_dim} numbers >= 0 (one per action "
                             f"dimension) or empty, got {self.loss_weights}")
        if (self.encoder == "perception") != bool(self.perception_sha256):
            raise ValueError("encoder 'perception' and perception_sha256 (the pretrained encoder's) go together")
        least = IMAGE_ENCODERS[self.encoder].min_side if self.images else 1
        if self.images and min(self.obs_shape[:2]) < least:
            raise ValueError(f"encoder {self.encoder!r} takes images of at least {least}×{least} pixels, got "
                             f"{self.obs_shape[0]}×{self.obs_shape[1]}")
        if self.network != "mlp" and self.images:
            raise ValueError(f"network {self.network!r} is for state observations; image policies use "
                             f"the encoder ({list(IMAGE_ENCODERS)})")
        if list(self.lr_boundaries) != sorted(self.lr_boundaries) or any(b < 1 for b in self.lr_boundaries):
            raise ValueError(f"lr_boundaries must be increasing steps >= 1, got {self.lr_boundaries}")
        if self.encoder_norm != "none" and not self.images:
            raise ValueError(f"encoder_norm {self.encoder_norm!r} is for the image encoders 'small', 'patch' and 'drq' "
                             f"(state policies: network='bn-mlp'), got obs_shape {self.obs_shape}")
        if self.augment_shift and not self.images:
            raise ValueError(f"augment_shift is for image observations, got {self.augment_shift} on obs_shape "
                             f"{self.obs_shape}")
        side = min(self.obs_shape[:2]) if self.images else 0
        if self.augment_shift > side // 4:
            raise ValueError(f"augment_shift must be an integer in [0, {side // 4}] (a quarter of the image's "
                             f"shorter side, {side}), got {self.augment_shift!r}")

    @property
    def images(self) -> bool:
        return len(self.obs_shape) == 3

    @property
    def frames(self) -> int:
        """Observations the policy sees: the current one and every `history_stride`-th step before it."""
        return (self.history - 1) // self.history_stride + 1

    def model(self) -> nn.Module:
        if self.images:
            norm = {} if self.encoder == "resnet18" else {"norm": self.encoder_norm}
            if self.encoder == "perception":
                norm["sha256"] = self.perception_sha256
            return IMAGE_ENCODERS[self.encoder](self.action_dim, dtype=self.dtype, **norm)
        return StatePolicy(self.action_dim, batchnorm=self.network == "bn-mlp", weights_init=self.init,
                           bn_momentum=self.bn_momentum, dtype=self.dtype)

    def optimizer(self) -> optax.GradientTransformation:
        """Adam's moment estimates; the learning rate is applied by hand (`adam_step`), so it can be traced."""
        return optax.scale_by_adam(b1=self.beta1, b2=self.beta2)


def action_errors(cfg: LearnerConfig, predicted: jax.Array, target: jax.Array) -> jax.Array:
    """`[...]` the BC loss of each sample, over the last axis: the squared (`cfg.loss` `"l2"`) or absolute (`"l1"`)
    error of each action dimension, weighted by `cfg.loss_weights` (none: 1 each) and summed. Every learner's BC
    term is its mean over the batch (weighted by the sample weights where a method has them)."""
    err = predicted - target
    err = err**2 if cfg.loss == "l2" else jnp.abs(err)
    if cfg.loss_weights:
        err = err * jnp.asarray(cfg.loss_weights, err.dtype)
    return jnp.sum(err, axis=-1)


@struct.dataclass
class Hparams:
    """Traced knobs of one configuration (stack them along a leading axis for a grid)."""

    weighting: Weighting
    lr: jax.Array               # [] float32
    history_dropout: jax.Array  # [] float32, probability of zeroing each past observation

    @classmethod
    def make(cls, kind: str = "uniform", lr: float = 2e-4, history_dropout: float = 0.0,
             **weighting_kw) -> Hparams:
        if not 0.0 <= history_dropout < 1.0:
            raise ValueError(f"history dropout must be in [0, 1), got {history_dropout}")
        if not lr > 0.0:
            raise ValueError(f"learning rate must be > 0, got {lr}")
        return cls(Weighting.make(kind, **weighting_kw), jnp.float32(lr), jnp.float32(history_dropout))


@struct.dataclass
class Data:
    """A training split on device; observations already standardised (states) or uint8 (images).

    obs `[M, *obs_shape]`, action `[M, A] float32`, t `[M] int32`: whole episodes; `rows` `[N] int32`: the
    split's rows among them (`None`: all `M`). ape `[N] float32` and `scores` `[S, N] float32` (the table the
    weightings read; `None`: just the APE) are per split row, by position in `rows`.
    """

    obs: jax.Array
    action: jax.Array
    t: jax.Array
    ape: jax.Array
    scores: jax.Array | None = None
    rows: jax.Array | None = None

    def score_table(self) -> jax.Array:
        return self.ape[None] if self.scores is None else self.scores

    @property
    def size(self) -> int:
        """`N`, the rows a minibatch is drawn from."""
        return int(self.obs.shape[0] if self.rows is None else self.rows.shape[0])

    def index(self, pos: jax.Array) -> jax.Array:
        """Row indices into `obs`/`action`/`t` of split positions `pos`."""
        return pos if self.rows is None else self.rows[pos]

    def sample(self, key: jax.Array, batch: int) -> tuple[jax.Array, jax.Array]:
        """`batch` positions drawn uniformly with replacement, and their rows: `([B], [B]) int32`."""
        pos = jax.random.randint(key, (batch,), 0, self.size)
        return pos, self.index(pos)


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
    init_policy: Callable[[jax.Array, Data], Any] | None = None  # fresh `cfg.model()` variables (`make_train`'s)


def scanned_learner(cfg: LearnerConfig, base: Learner, init: Callable[[jax.Array, Any, Data], Any],
                    update: Callable[[Any, Any, Data], tuple[Any, dict]],
                    policy_params: Callable[[Any], Any] = lambda state: state.params) -> Learner:
    """A one-round learner on BC's network (`base`: `make_train(cfg)`'s policy input, per-sample loss and policy
    init): `run` scans `update(state, hp, data) -> (state, metrics)` `n` times, `train` runs `cfg.iterations` from
    `init` and returns `policy_params` of the end state. FCA, RAP, PALR and MINE are built this way."""
    def run(state: Any, hp: Any, data: Data, n: int):
        return jax.lax.scan(lambda s, _: update(s, hp, data), state, None, length=n, unroll=cfg.unroll)

    def train(key: jax.Array, hp: Any, data: Data):
        state, metrics = run(init(key, hp, data), hp, data, cfg.iterations)
        return policy_params(state), metrics

    return Learner(init=init, run=run, train=train, policy_input=base.policy_input,
                   per_sample_loss=base.per_sample_loss, policy_params=policy_params,
                   round_iterations=cfg.iterations, init_policy=base.init_policy)


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


def random_shift(key: jax.Array, frames: jax.Array, pad: int) -> jax.Array:
    """`[B, H, h, w, C]` frames, each sample's `H` frames shifted by one random offset in `[−pad, pad]²`.

    The random-shift augmentation of image-based control (DrQ: Kostrikov, Yarats and Fergus, 2020): the frames
    are padded by `pad` pixels, repeating the edge, and a window of the original size is cut at an offset drawn
    uniformly per sample. Every frame of a sample's history gets the same shift, so the motion between them is
    kept. Integer offsets: the pixels are copied, not interpolated.
    """
    b, h, w = frames.shape[0], frames.shape[2], frames.shape[3]
    padded = jnp.pad(frames, ((0, 0), (0, 0), (pad, pad), (pad, pad), (0, 0)), mode="edge")
    offsets = jax.random.randint(key, (b, 2), 0, 2 * pad + 1)
    cut = lambda x, o: jax.lax.dynamic_slice(x, (0, o[0], o[1], 0), (x.shape[0], h, w, x.shape[3]))  # noqa: E731
    return jax.vmap(cut)(padded, offsets)


def augment(cfg: LearnerConfig, key: jax.Array, history_obs: jax.Array) -> jax.Array:
    """A training batch's `[B, H, *obs_shape]` observations as `cfg` augments them (`augment_shift`:
    `random_shift`); unchanged (and `key` unused) without augmentation. Training only: evaluation and the
    diagnostics read the frames as they are."""
    return random_shift(key, history_obs, cfg.augment_shift) if cfg.augment_shift else history_obs


def drop_history(key: jax.Array, history: jax.Array, p: jax.Array | float) -> jax.Array:
    """HistoryDropout: each past observation of `history [B, H, ...]` zeroed with probability `p`.

    The current (last) observation is always kept; draws are independent per
    sample and frame. `p = 0` returns `history` unchanged.
    """
    keep = jax.random.uniform(key, history.shape[:2]) >= p
    keep = keep.at[:, -1].set(True)
    return jnp.where(keep.reshape(keep.shape + (1,) * (history.ndim - 2)), history, jnp.zeros((), history.dtype))


def dataset_losses(learner: Learner, params: Any, data: Data, chunk: int | None = None) -> jax.Array:
    """`[N]` unweighted loss of every split row of `data` under policy `params`, `chunk` rows at a time.

    The chunks run in a `lax.map`, so memory holds one chunk's activations
    whatever `N` is, and the program's size does not grow with `N`. Default
    chunk: 256 frames for images (a CNN's activations are large), 4,096 rows
    of states.
    """
    n = data.size
    chunk = chunk or (256 if data.obs.ndim >= 4 else 4096)
    chunk = max(1, min(chunk, n))
    rounds = -(-n // chunk)
    pos = jnp.arange(rounds * chunk).reshape(rounds, chunk) % n  # the last chunk wraps around; cut off below
    losses = jax.lax.map(lambda p: learner.per_sample_loss(params, data, data.index(p)), pos)
    return losses.reshape(-1)[:n]


def lr_schedule(cfg: LearnerConfig) -> optax.Schedule:
    """The learning rate's factor over a run, an optax schedule (`step -> factor`, traceable):

    - `"piecewise"` (the paper's): `lr_decay^k`, `k` the boundaries of `cfg.lr_boundaries` that `step` has reached;
    - `"constant"`: 1;
    - `"cosine"`: from 0 to 1 over `cfg.warmup_steps`, then a cosine to 0 at `cfg.iterations`
      (`optax.warmup_cosine_decay_schedule`).

    The traced learning rate of a configuration (`Hparams.lr`) is multiplied by it at each step
    (`learning_rate`), which is what `optax.inject_hyperparams` would do, with the rate a grid axis.
    """
    if cfg.lr_schedule == "constant":
        return optax.constant_schedule(1.0)
    if cfg.lr_schedule == "cosine":
        return optax.warmup_cosine_decay_schedule(0.0, 1.0, cfg.warmup_steps, cfg.iterations)
    boundaries, decay = cfg.lr_boundaries, cfg.lr_decay

    def piecewise(step):
        passed = sum((step >= b).astype(jnp.float32) for b in boundaries) if boundaries else 0.0
        return decay ** jnp.asarray(passed, jnp.float32)

    return piecewise


def learning_rate(cfg: LearnerConfig, lr: jax.Array, step: jax.Array) -> jax.Array:
    """The learning rate every learner uses at `step`: `lr` × `lr_schedule(cfg)(step)` (traced `lr` and `step`)."""
    return lr * lr_schedule(cfg)(step)


def lr_boundaries(iterations: int, fractions: tuple[float, ...]) -> tuple[int, ...]:
    """Steps at which a run of `iterations` drops its learning rate: `ceil(f · iterations)` for each fraction
    `f` (the paper's 1/3 and 2/3: 100k and 200k of 300k); boundaries at or past the end are dropped."""
    steps = sorted({max(1, math.ceil(f * iterations - 1e-9)) for f in fractions})
    return tuple(b for b in steps if b < iterations)


def adam_step(adam: optax.GradientTransformation, params: Any, grads: Any, opt_state: Any, lr: jax.Array
              ) -> tuple[Any, Any]:
    """One step of a `scale_by_adam` transform with the learning rate applied by hand (so it can be traced)."""
    updates, opt_state = adam.update(grads, opt_state)
    return jax.tree.map(lambda p, u: p - lr * u, params, updates), opt_state


def trainable(variables: Any) -> dict:
    """The part of a policy's variables the optimiser moves: `{"params": ...}` (BatchNorm's statistics are not)."""
    return {"params": variables["params"]}


def policy_apply(model: nn.Module, variables: Any, x: jax.Array, train: bool = False, **kw) -> tuple[Any, Any]:
    """`model` applied to `x`: `(output, variables)`.

    `train=True` on a network with BatchNorm normalises by the batch's statistics and returns the variables
    with the running statistics updated; otherwise the running statistics are used and `variables` come back
    unchanged.
    """
    if train and "batch_stats" in variables:
        out, updated = model.apply(variables, x, train=True, mutable=["batch_stats"], **kw)
        return out, {**variables, **updated}
    return model.apply(variables, x, **kw), variables


def gradient_step(adam: optax.GradientTransformation, variables: Any, opt_state: Any, lr: jax.Array,
                  loss_fn: Callable[[Any], tuple[jax.Array, tuple[Any, Any]]]) -> tuple[Any, Any, jax.Array, Any]:
    """One Adam step of a policy on `loss_fn(variables) -> (loss, (aux, variables after the forward pass))`.

    Returns `(variables, opt_state, loss, aux)`: the parameters moved, BatchNorm's running statistics as the
    forward pass left them.
    """
    def objective(params):
        return loss_fn({**variables, **params})

    (loss, (aux, after)), grads = jax.value_and_grad(objective, has_aux=True)(trainable(variables))
    params, opt_state = adam_step(adam, trainable(variables), grads, opt_state, lr)
    return {**after, **params}, opt_state, loss, aux


def make_train(cfg: LearnerConfig) -> Learner:
    """The pure functions of one learner setup (see the module docstring)."""
    model = cfg.model()
    adam = cfg.optimizer()

    def policy_input(history_obs: jax.Array) -> jax.Array:
        """`[..., H, *obs_shape]` -> the model's input (flattened states, or frames on channels in [0, 1]) of the
        frames the policy sees (every `history_stride`-th)."""
        if cfg.history_stride > 1:
            history_obs = jnp.take(history_obs, np.arange(0, cfg.history, cfg.history_stride),
                                   axis=-1 - len(cfg.obs_shape))
        if not cfg.images:
            return history_obs.reshape(history_obs.shape[:-2] + (-1,)).astype(jnp.float32)
        x = jnp.moveaxis(history_obs, -4, -2)  # [..., h, w, H, 3]
        return x.reshape(x.shape[:-2] + (-1,)).astype(jnp.float32) / 255.0

    def batch(data: Data, idx: jax.Array, dropout_key: jax.Array | None = None, dropout=0.0,
              augment_key: jax.Array | None = None) -> jax.Array:
        obs = data.obs[history_index(data.t, idx, cfg.history)]  # [B, H, *obs_shape]
        if dropout_key is not None:
            obs = drop_history(dropout_key, obs, dropout)
        if augment_key is not None:
            obs = augment(cfg, augment_key, obs)
        return policy_input(obs)

    def errors(predicted: jax.Array, target: jax.Array) -> jax.Array:
        return action_errors(cfg, predicted, target)

    def per_sample_loss(params, data: Data, idx: jax.Array, dropout_key=None, dropout=0.0) -> jax.Array:
        """`[B]` loss of rows `idx` (indices into `data.obs`, not split positions), running statistics."""
        return errors(model.apply(params, batch(data, idx, dropout_key, dropout)), data.action[idx])

    def init_policy(key: jax.Array, data: Data) -> Any:
        """Fresh policy variables (`init` of every learner that trains `cfg.model()`)."""
        if data.size < cfg.batch_size:
            raise ValueError(f"the training set has {data.size} samples, fewer than the batch size "
                             f"{cfg.batch_size}")
        return model.init(key, policy_input(jnp.zeros((1, cfg.history, *cfg.obs_shape), data.obs.dtype)))

    def init(key: jax.Array, hp: Hparams, data: Data) -> TrainState:
        key_init, key_run = jax.random.split(key)
        params = init_policy(key_init, data)
        return TrainState(params=params, opt_state=adam.init(trainable(params)), step=jnp.zeros((), jnp.int32),
                          key=key_run, static_weights=weighting.dataset_weights(data.score_table(), hp.weighting))

    def update(state: TrainState, hp: Hparams, data: Data):
        key_step = jax.random.fold_in(state.key, state.step)
        pos, idx = data.sample(key_step, cfg.batch_size)
        key_drop = jax.random.fold_in(key_step, 1)
        w = weighting.batch_weights(data.score_table(), state.static_weights, pos, hp.weighting)
        x = batch(data, idx, key_drop, hp.history_dropout, augment_key=jax.random.fold_in(key_step, 2))

        def loss_fn(variables):
            predicted, variables = policy_apply(model, variables, x, train=True)
            ell = errors(predicted, data.action[idx])
            return jnp.mean(w * ell), (jnp.mean(ell), variables)

        params, opt_state, weighted, unweighted = gradient_step(
            adam, state.params, state.opt_state, learning_rate(cfg, hp.lr, state.step), loss_fn)
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
                   round_iterations=cfg.iterations, init_policy=init_policy)
