"""RAP, residual action prediction (Chuang, Yang, Wen and Gao, ECCV 2022, "Resolving Copycat Problems in Visual
Imitation Learning via Residual Action Prediction"), as a pure-functional `Learner` on state observations and on
images through the patch encoder.

Two branches. A *memory* branch `M` reads the whole observation history and a residual head `R` on its features
`m` predicts the action's change `a_t − a_{t−1}`; a *policy* branch reads the current observation alone, and the
policy's head reads both branches' features `[m, h]` and outputs `a_t`. The memory learns from the residual loss,
not from the policy's (the authors' code detaches `m` before the policy reads it), so what the history adds to
the policy is what predicts the change, not the previous action itself. Per minibatch (`weight` = λ ∈ [0, 1]):

    L_BC  = mean_i ℓ(π(o_t, m), a_t),     L_res = mean_i ℓ(R(m), a_t − a_{t−1}),
    ∇ memory      = (1 − λ) ∇L_BC + λ ∇L_res,     ∇ policy branch and head = ∇L_BC,     ∇ R = λ ∇L_res,

`ℓ` the project's loss (squared error summed over action dimensions; absolute error for L1 tasks). λ = 1 (the
default) is the authors' RAP: the memory sees no gradient of the policy's loss. λ = 0 is BC-OH on RAP's network:
BC-OH's loss, its gradient reaching every weight, the residual head idle. In between, `1 − λ` of the policy's
gradient leaks into the memory. Under Adam only the ratio of the two gradients matters, so λ is a traced knob
on [0, 1] (`RapHparams`), and so is the memory's width: its `weights` × `widths` (`RapKnobs`) train in one
vmapped program. (Both implementations we read train each branch with its own optimiser; λ = 1 is theirs.)

**The network is BC-OH's `StatePolicy`, split in two.** The memory is the first `memory_width` units of each of
the three encoder layers and the first `round(memory_width / 3)` of the 100-unit embedding; the policy branch the
rest. Masks on the kernels (`branch_masks`) keep the branches apart: the memory's first layer reads every frame of
the history, the policy branch's the current frame only; each later encoder layer and the embedding read their
own branch; the head reads the whole embedding. The kernels are stored masked (zeros where a branch may not read)
and masked in every forward pass, so those weights get no gradient and stay zero: the trained policy *is* a
`StatePolicy`, and evaluation, the loss analysis, the copycat probes and checkpoints read it as they read BC-OH's.
The gradient's split at the head's input (`1 − λ` on the memory's units) is a stop-gradient mixed in by
`flax.linen.intercept_methods` on the head's `Dense`, so one backward pass computes both losses' gradients.
At init each masked kernel's columns are rescaled by `sqrt(fan_in / kept fan_in)`, so a unit starts with the
variance of a layer as wide as its branch. BatchNorm (`network="bn-mlp"`) normalises each unit on its own and
splits with them.

Defaults: λ = 1 (the authors' stop-gradient) and `memory_width` 150 (half the units: both implementations make the
branches equally wide, PALR's RAP 128 and 64 units each, RAP's code 512 memory features beside 512 perception
features); the residual head one hidden layer of 300 with LeakyReLU(0.2) (PALR's RAP: one of 128). Our readings:

- **Capacity**: the two branches share BC-OH's 300 units per layer, where both implementations give each branch a
  network as wide as BC's; at width 150 RAP has ~60% of BC-OH's weights (block-diagonal layers). The same network
  is what lets every later phase treat RAP as BC-OH.
- **The memory reads the current frame too** (both implementations feed it the whole stack); the policy branch
  reads only the current frame (RAP's code zeroes the past frames of its input).
- **The previous action** at an episode's first step repeats the first action (`ape_jax.baselines._batch`), so
  the residual there is 0.
- **Images: the patch encoder** (`PatchPolicy`, `recipe.encoder=patch`), split the same way, so the trained policy
  is a plain `PatchPolicy`. Its one patch layer (`patch_0`, `[p·p·3H, 64]`) plays the first encoder layer: the
  memory's channels (the first of the 64) read every entry of a patch, the policy branch's only the current
  frame's (the last 3 of each pixel's `3H` channels, at every pixel of the patch). The embedding's memory units
  read the memory's channels at every cell of the `[h/8, w/8, 64]` grid (flattened cell-major, channel-minor),
  its policy units the policy's; the head reads the whole embedding. `memory_width` keeps its units of
  `StatePolicy`'s 300: each layer gets the same share (`memory_units`), so a recipe's `rap_widths` mean the same
  fraction for both kinds of policy. With GroupNorm (`encoder_norm="group"`: `GROUPS` = 8 groups of 8
  consecutive channels, each normalised by its own statistics) the memory's channels are rounded to whole groups,
  at least one on each side (width 150: 4 groups, 32 channels; 60: 2 groups, 16), so no group mixes the
  branches and the policy branch's channels stay functions of the current frame. Other image encoders are
  refused: their stacked convolutions would need masks of their own.
- **A history of at least 2** is needed (a memory of the current frame alone is the policy branch).

Metrics (`[n]` float32 per `run` of `n` iterations): `"loss"` (`L_BC + λ L_res`), `"unweighted_loss"` (`L_BC`),
`"residual_loss"` (`L_res`) and `"zero_residual_loss"` (`L_res` of predicting no change, the bar `R` must pass).
"""

from __future__ import annotations

import dataclasses

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from ape_jax import methods
from ape_jax.baselines._batch import Batch, errors, sample_batch
from ape_jax.knobs import axis, positive
from ape_jax.learner import (Data, Learner, LearnerConfig, adam_step, learning_rate, make_train, scanned_learner,
                             trainable)
from ape_jax.models import GROUPS, StatePolicy

DEFAULT_WEIGHT = 1.0   # both implementations: the memory learns from the residual loss alone
DEFAULT_WIDTH = 150    # half of StatePolicy's 300 units: the branches equally wide, as in both implementations
UNITS = StatePolicy.hidden[0]  # the memory's width is counted in the state policy's units (images: shares)
RESIDUAL_HIDDEN = 300
UNITS = StatePolicy.hidden[0]   # the encoder's units per layer, split between the branches
ENCODERS = tuple(f"encoder_{i}" for i in range(len(StatePolicy.hidden)))
PATCH = "patch_0"      # PatchPolicy's patch layer, RAP's first layer on images
RGB = 3                # channels of one frame (image observations are `[height, width, 3]`)


class ResidualHead(nn.Module):
    """`R`: `[B, E]` memory features (the policy branch's embedding units zeroed) -> `[B, A]` predicted change."""

    action_dim: int
    hidden: int = RESIDUAL_HIDDEN

    @nn.compact
    def __call__(self, memory: jax.Array) -> jax.Array:
        h = nn.leaky_relu(nn.Dense(self.hidden, name="hidden")(memory), negative_slope=0.2)
        return nn.Dense(self.action_dim, name="residual")(h)


@struct.dataclass
class RapHparams:
    """Traced knobs of one RAP run (stack them along a leading axis for seeds × weights × widths)."""

    weight: jax.Array        # [] float32, λ in [0, 1]: the residual loss's share of the memory's gradient
    # [] float32, an integer in [1, UNITS - 1]: the memory's units of StatePolicy's UNITS per encoder layer (each
    # other layer, and a PatchPolicy's channels, the same share: `memory_units`)
    memory_width: jax.Array
    lr: jax.Array            # [] float32

    @classmethod
    def make(cls, weight: float = DEFAULT_WEIGHT, memory_width: float = DEFAULT_WIDTH, lr: float = 2e-4
             ) -> RapHparams:
        """Validated hyperparameters (`ValueError`, one line, for a value out of range)."""
        if not 0.0 <= weight <= 1.0:
            raise ValueError(f"RAP weight must be in [0, 1] (the residual loss's share of the memory's gradient), "
                             f"got {weight}")
        if not (float(memory_width).is_integer() and 1 <= memory_width <= UNITS - 1):
            raise ValueError(f"RAP memory_width must be an integer in [1, {UNITS - 1}] (units of the encoder's "
                             f"{UNITS}), got {memory_width}")
        positive("learning rate", lr)
        return cls(weight=jnp.float32(weight), memory_width=jnp.float32(memory_width), lr=jnp.float32(lr))


@struct.dataclass
class RapState:
    """The scan carry: the two-branch policy (a masked `StatePolicy`), the residual head, their moments."""

    params: Any          # cfg.model() variables, kernels masked (`branch_masks`)
    opt_state: Any       # on trainable(params)
    residual: Any        # ResidualHead variables
    residual_opt: Any
    step: jax.Array      # [] int32
    key: jax.Array


def memory_units(width: jax.Array | float, units: int, groups: int | None = None) -> jax.Array:
    """`[units] bool`: the memory branch's units of a layer of `units` when `width` of `UNITS` are the memory's:
    the first ones, the same share rounded, at least one unit on each side.

    With `groups` (GroupNorm's, which normalises each run of `units // groups` consecutive units together) the
    share is rounded to whole groups instead, at least one group on each side, so no group mixes the branches.
    """
    groups = units if groups is None else groups
    share = jnp.clip(jnp.round(jnp.asarray(width, jnp.float32) * groups / UNITS), 1, groups - 1)
    return jnp.arange(units) < share * (units // groups)


def branch_masks(params: dict, history: int, width: jax.Array | float) -> dict:
    """Which kernel entries each branch may use: `{layer: [in, out] float32}` for the encoder's layers and the
    Head's `embedding` (1: kept, 0: held at zero); every other weight is unmasked.

    Args:
      params: a `StatePolicy`'s or a `PatchPolicy`'s `{"params": ...}` entry (its kernels' shapes are read, not
        their values).
      history: frames in the input, oldest first: a `StatePolicy`'s `[H * D]` (the last `D` entries are the
        current frame); a `PatchPolicy`'s patch entries in (row, column, channel) order with `3H` channels per
        pixel (the last 3 of each pixel are the current frame's).
      width: the memory's units of `UNITS` (traced; `memory_units` gives each layer's share).

    Returns:
      The masks, keyed by layer name: `encoder_0`..`encoder_2` (states) or `patch_0` (images), and `embedding`.
    """
    if "Head_0" in params and PATCH in params:
        masks, features = _patch_masks(params, history, width)
    elif "Head_0" in params and all(name in params for name in ENCODERS):
        masks, features = _state_masks(params, history, width)
    else:
        raise ValueError(f"RAP splits a StatePolicy (layers {', '.join(ENCODERS)}, Head_0) or a PatchPolicy "
                         f"({PATCH}, Head_0); got layers {sorted(params)}")
    n_out = params["Head_0"]["embedding"]["kernel"].shape[1]
    masks["embedding"] = (features[:, None] == memory_units(width, n_out)[None, :]).astype(jnp.float32)
    return masks


def _state_masks(params: dict, history: int, width: jax.Array | float) -> tuple[dict, jax.Array]:
    """The encoder layers' masks, and `[300] bool`: which of the embedding's inputs are the memory's."""
    masks = {}
    for i, name in enumerate(ENCODERS):
        n_in, n_out = params[name]["kernel"].shape
        out_memory = memory_units(width, n_out)
        if i == 0:  # the memory reads every frame, the policy branch the current one (the last D inputs)
            current = jnp.arange(n_in) >= n_in - n_in // history
            keep = out_memory[None, :] | current[:, None]
        else:
            keep = memory_units(width, n_in)[:, None] == out_memory[None, :]
        masks[name] = keep.astype(jnp.float32)
    return masks, out_memory


def _patch_masks(params: dict, history: int, width: jax.Array | float) -> tuple[dict, jax.Array]:
    """`patch_0`'s mask, and `[cells * C] bool`: which of the embedding's inputs (the flattened `[h/8, w/8, C]`
    grid, cell-major) are the memory's channels."""
    if "patch_1" in params:
        raise ValueError("RAP splits a PatchPolicy of one patch layer (the default); got layers "
                         f"{sorted(params)}")
    n_in, channels = params[PATCH]["kernel"].shape
    pixel = RGB * history
    if n_in % pixel:
        raise ValueError(f"RAP: {PATCH}'s {n_in} inputs are not whole pixels of {history} frames × {RGB} channels")
    groups = GROUPS if "norm_0" in params else None   # GroupNorm after the patch layer (`models.encoder_norm`)
    if groups is not None and channels % groups:
        raise ValueError(f"RAP: GroupNorm's {groups} groups do not divide {PATCH}'s {channels} channels")
    out_memory = memory_units(width, channels, groups)
    current = jnp.arange(n_in) % pixel >= pixel - RGB   # the last frame's channels of every pixel of the patch
    embed_in = params["Head_0"]["embedding"]["kernel"].shape[0]
    masks = {PATCH: (out_memory[None, :] | current[:, None]).astype(jnp.float32)}
    return masks, jnp.tile(out_memory, embed_in // channels)


def _map_kernels(params: dict, masks: dict, fn) -> dict:
    """`params` with each masked kernel replaced by `fn(kernel, mask)` (the Head's `embedding` under `Head_0`)."""
    out = {**params, **{name: {**params[name], "kernel": fn(params[name]["kernel"], mask)}
                        for name, mask in masks.items() if name != "embedding"}}
    head = params["Head_0"]
    out["Head_0"] = {**head, "embedding": {**head["embedding"],
                                           "kernel": fn(head["embedding"]["kernel"], masks["embedding"])}}
    return out


def apply_masks(params: dict, masks: dict) -> dict:
    """`params` (a `StatePolicy`'s or `PatchPolicy`'s `{"params": ...}` entry) with its masked kernels multiplied
    by their masks (`branch_masks`)."""
    return _map_kernels(params, masks, lambda kernel, mask: kernel * mask)


def _rescaled(params: dict, masks: dict) -> dict:
    """Fresh kernels masked, each column scaled by `sqrt(fan_in / kept fan_in)` (module docstring)."""
    def scale(kernel, mask):
        kept = jnp.maximum(mask.sum(axis=0, keepdims=True), 1.0)
        return kernel * mask * jnp.sqrt(kernel.shape[0] / kept)

    return _map_kernels(params, masks, scale)


def rap_loss(cfg: LearnerConfig, variables: Any, residual: Any, batch: Batch, weight: jax.Array,
             width: jax.Array) -> tuple[jax.Array, tuple[tuple[jax.Array, jax.Array, jax.Array], Any]]:
    """RAP's objective on one batch: `L_BC + λ L_res`, its gradient split at the head's input (module docstring).

    Args:
      cfg: the program's config (`cfg.model()` a `StatePolicy` or a `PatchPolicy`).
      variables: the policy's variables (`{"params": ...}`, plus `{"batch_stats": ...}` for BatchNorm).
      residual: the `ResidualHead`'s variables.
      batch: the minibatch (`_batch.sample_batch`).
      weight: λ in [0, 1] (traced).
      width: the memory's units of `UNITS` (traced).

    Returns:
      `(loss, ((L_BC, L_res, L_res of predicting zero), variables after the forward pass))`: `[] float32` each;
      the variables carry BatchNorm's updated running statistics.
    """
    model = cfg.model()
    masked = {**variables, "params": apply_masks(variables["params"], branch_masks(variables["params"], cfg.frames,
                                                                                    width))}
    memory = memory_units(width, variables["params"]["Head_0"]["embedding"]["kernel"].shape[1]).astype(jnp.float32)

    def split_gradient(next_fun, args, kwargs, context):
        # the head's input: the memory's units pass (1 − λ) of the policy's gradient back, the same value forward
        if isinstance(context.module, nn.Dense) and context.module.name == "head" and context.method_name == "__call__":
            h = args[0]
            args = (h - weight * memory * (h - jax.lax.stop_gradient(h)), *args[1:])
        return next_fun(*args, **kwargs)

    train = "batch_stats" in variables
    with nn.intercept_methods(split_gradient):
        if train:
            (predicted, embedding), updated = model.apply(masked, batch.x, train=True, return_embedding=True,
                                                          mutable=["batch_stats"])
            after = {**variables, **updated}
        else:
            predicted, embedding = model.apply(masked, batch.x, return_embedding=True)
            after = variables
    change = batch.action - batch.previous
    bc = jnp.mean(errors(cfg, predicted, batch.action))
    res = jnp.mean(errors(cfg, ResidualHead(cfg.action_dim).apply(residual, embedding * memory), change))
    zero = jnp.mean(errors(cfg, jnp.zeros_like(change), change))
    return bc + weight * res, ((bc, res, zero), after)


def predict_residual(cfg: LearnerConfig, state: RapState, width: jax.Array | float, x: jax.Array) -> jax.Array:
    """`[B, A]`: the memory's predicted change `a_t − a_{t−1}` for policy inputs `x` (`[B, H * D]` states or
    `[B, h, w, 3H]` frames; running statistics, as evaluation applies the policy)."""
    _, embedding = cfg.model().apply(state.params, x, return_embedding=True)
    memory = memory_units(width, embedding.shape[-1]).astype(jnp.float32)
    return ResidualHead(cfg.action_dim).apply(state.residual, embedding * memory)


def make_rap(cfg: LearnerConfig) -> Learner:
    """The pure functions of RAP for one static setup (the module docstring).

    Args:
      cfg: shapes, counts and the recipe; state observations (`cfg.model()` a `StatePolicy`) or images through
        the patch encoder (`cfg.encoder == "patch"`, a `PatchPolicy`), and `cfg.history` >= 2.

    Returns:
      A `Learner` whose policy parameters are a `StatePolicy`'s or a `PatchPolicy`'s; `init(key)` draws the
      policy and run key as `make_train(cfg).init(jax.random.split(key)[0])` does (then masks them) and the
      residual head from the other half.
    """
    if cfg.images and cfg.encoder != "patch":
        raise ValueError(f"RAP splits the state policy's layers or the patch encoder's channels into its two "
                         f"branches; image encoder {cfg.encoder!r} is not supported (use encoder='patch')")
    if cfg.history < 2:
        raise ValueError(f"RAP needs a history of at least 2 observations (its memory reads the past), got "
                         f"{cfg.history}")
    base = make_train(cfg)
    adam = cfg.optimizer()
    head = ResidualHead(cfg.action_dim)

    def init(key: jax.Array, hp: RapHparams, data: Data) -> RapState:
        key_policy, key_residual = jax.random.split(key)
        key_init, key_run = jax.random.split(key_policy)  # make_train's init of key_policy
        variables = base.init_policy(key_init, data)
        params = _rescaled(variables["params"], branch_masks(variables["params"], cfg.frames, hp.memory_width))
        variables = {**variables, "params": params}
        embed = params["Head_0"]["embedding"]["kernel"].shape[1]
        residual = head.init(key_residual, jnp.zeros((1, embed), jnp.float32))
        return RapState(params=variables, opt_state=adam.init(trainable(variables)), residual=residual,
                        residual_opt=adam.init(residual), step=jnp.zeros((), jnp.int32), key=key_run)

    def update(state: RapState, hp: RapHparams, data: Data):
        batch = sample_batch(cfg, base, data, jax.random.fold_in(state.key, state.step))
        lr = learning_rate(cfg, hp.lr, state.step)

        def objective(params, residual):
            return rap_loss(cfg, {**state.params, **params}, residual, batch, hp.weight, hp.memory_width)

        (loss, ((bc, res, zero), after)), (grads, residual_grads) = jax.value_and_grad(
            objective, argnums=(0, 1), has_aux=True)(trainable(state.params), state.residual)
        params, opt_state = adam_step(adam, trainable(state.params), grads, state.opt_state, lr)
        residual, residual_opt = adam_step(adam, state.residual, residual_grads, state.residual_opt, lr)
        state = state.replace(params={**after, **params}, opt_state=opt_state, residual=residual,
                              residual_opt=residual_opt, step=state.step + 1)
        return state, {"loss": loss, "unweighted_loss": bc, "residual_loss": res, "zero_residual_loss": zero}

    return scanned_learner(cfg, base, init, update)


def refusal(settings, obs: str) -> str | None:
    """Why RAP cannot run under a sweep's settings (`Method.refuses`), or None."""
    if obs == "image" and settings.recipe.encoder != "patch":
        return (f"rap on images needs the patch encoder (its branches split PatchPolicy's channels), got "
                f"recipe.encoder={settings.recipe.encoder!r}; use --set recipe.encoder=patch")
    if settings.protocol.history < 2:
        return (f"rap needs a history (protocol.history >= 2: its memory reads the past), got "
                f"protocol.history={settings.protocol.history}")
    return None


@dataclasses.dataclass(frozen=True)
class RapKnobs:
    """RAP's own settings (`--set rap.KNOB=VALUE`; the module docstring). Every pair of the two axes runs.

    Attributes:
      weights: the residual loss's shares λ of the memory's gradient, each in [0, 1]; default `DEFAULT_WEIGHT`.
      widths: the memory's widths in encoder units, each in [1, `UNITS` − 1] (of `StatePolicy`'s 300; images: the
        same share of the patch encoder's channels); default `DEFAULT_WIDTH`.
    """

    weights: tuple[float, ...] = (DEFAULT_WEIGHT,)
    widths: tuple[int, ...] = (DEFAULT_WIDTH,)

    def __post_init__(self):
        axis("weights", self.weights, _share)
        axis("widths", self.widths, _width)


def _share(name: str, v: float) -> None:
    if not 0.0 <= v <= 1.0:
        raise ValueError(f"{name}: every value must be in [0, 1] (the residual loss's share of the memory's "
                         f"gradient), got {v}")


def _width(name: str, v: int) -> None:
    if not (isinstance(v, int) and not isinstance(v, bool) and 1 <= v < UNITS):
        raise ValueError(f"{name}: every value must be an integer in [1, {UNITS - 1}] (memory units of the "
                         f"encoder's {UNITS}), got {v!r}")


def _grid(ctx) -> list[dict]:
    knobs = ctx.knobs_of("rap")
    return [{"weight": w, "memory_width": float(m)} for w in knobs.weights for m in knobs.widths]


methods.register(methods.Method(
    "rap", "RAP", grid=_grid,
    hparams=lambda settings, lr, row: RapHparams.make(settings["weight"], settings["memory_width"], lr=lr),
    program="rap", learner=lambda ctx: make_rap(ctx.cfg), refuses=refusal, module=__name__, knobs=RapKnobs))
