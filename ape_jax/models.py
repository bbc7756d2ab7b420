"""Policies: observation history -> action.

- `StatePolicy` — for state observations, in the style of the copycat paper's
  network: three hidden layers of 300, a 100-unit embedding, a 300-unit head,
  LeakyReLU(0.2). Input: the last `H` observations, flattened `[..., H * D]`.
  With `batchnorm=True` it is the FCA code's network (`gan_mlp.py`): each
  encoder layer is a bias-free Dense → BatchNorm → LeakyReLU, and the head
  applies LeakyReLU to the embedding before its 300 units; `weights_init="xavier"`
  gives its xavier-uniform kernels (biases zero, BatchNorm's scale ~ N(1, 0.02)).
- `ImagePolicy` — for images: a small conv encoder (CPU-sized) to the same
  100-unit embedding and head. Input: the last `H` frames stacked on channels,
  `[..., height, width, 3 * H]`, already scaled to [0, 1].

- `PatchPolicy` — for images on a CPU: one 8×8 patch embedding (a convolution
  with kernel = stride = 8, computed as a matrix product) to the same head; ~5×
  the small encoder's training speed on XLA:CPU, fit for `lax.scan` and `vmap`.

- `DrQPolicy` — the field's pixel encoder (DrQ / DrQ-v2): four 3×3 convolutions of 32
  channels, the first of stride 2, ReLU, on 84×84 frames, to the same head; its
  convolutions are matrix products over 3×3 windows (im2col), fit for `lax.scan`.

- `PerceptionPolicy` — a task's pretrained perception encoder (`ape_jax.perception`) fine-tuned
  end to end, each frame's embedding to the state policy's network.

- `ResNet18Policy` — for images on a GPU: the supplement's MuJoCo-Image
  network, "ResNet-18 with a two-layer 300-unit MLP head" (details and our
  readings in its docstring). Same input as `ImagePolicy`.

All take `return_embedding=True` to return `(action, embedding)`, the
embedding being the Head's 100-unit `embedding` layer (for FCA's adversary);
the parameters are the same either way. All take `dtype` (`DTYPES`): the dtype of
their arithmetic; `"bfloat16"` is mixed precision — parameters stay float32 (Flax's
`param_dtype`), each layer computes in bfloat16, and the action and embedding come
back as float32, so the loss and the optimiser see float32 as with `"float32"`.
"""

from __future__ import annotations

from typing import ClassVar
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from ape_jax.patches import patchify  # noqa: F401 (the patch policy's; imported from here too)


def _lrelu(x: jax.Array) -> jax.Array:
    return nn.leaky_relu(x, negative_slope=0.2)


# Dense kernel initialisers by name: Flax's default (LeCun normal) and the FCA code's (xavier uniform).
INITS = {"lecun": nn.initializers.lecun_normal(), "xavier": nn.initializers.xavier_uniform()}


# the policies' arithmetic (`LearnerConfig.dtype`, `recipe.dtype`): parameters and optimiser state stay float32
DTYPES = ("float32", "bfloat16")


def bf16_problem() -> str | None:
    """Why this process's default backend cannot train in bfloat16, or None when it can.

    XLA compiles bfloat16 on every backend, so "has no bfloat16" means has no bfloat16 *arithmetic*: a GPU
    before compute capability 8.0 (Ampere) emulates it in float32, slower than float32 itself. XLA:CPU also
    computes bfloat16 by widening, but a CPU is where the tests and the smoke runs check that the knob gives
    float32's results, so it is accepted (`experiments.bench_images` measures its speed there). Other platforms
    (a plugin without bfloat16 kernels) are refused.
    """
    device = jax.devices()[0]
    if device.platform in ("cpu", "tpu"):
        return None
    if device.platform == "gpu":
        capability = getattr(device, "compute_capability", None)
        try:
            if capability is not None and float(capability) >= 8.0:
                return None
        except (TypeError, ValueError):
            pass
        return (f"the GPU {device.device_kind} (compute capability {capability}) has no bfloat16 arithmetic "
                f"(Ampere, 8.0, or later)")
    return f"the {device.platform} backend has no bfloat16 arithmetic"


def _out(x: jax.Array) -> jax.Array:
    """A policy's outputs (action, embedding) as float32, whatever its arithmetic's dtype."""
    return x.astype(jnp.float32)


def _bn_scale_init(key: jax.Array, shape, dtype=jnp.float32) -> jax.Array:
    """BatchNorm's scale ~ N(1, 0.02), as the FCA code (and DCGAN) initialise it."""
    return 1.0 + 0.02 * jax.random.normal(key, shape, dtype)


class Head(nn.Module):
    """Embedding (100) -> 300 -> action; `activate_embedding`: LeakyReLU on the embedding first (FCA's head)."""

    action_dim: int
    embed: int = 100
    hidden: int = 300
    weights_init: str = "lecun"
    activate_embedding: bool = False
    dtype: str = "float32"

    @nn.compact
    def __call__(self, features: jax.Array, return_embedding: bool = False,
                 embedding_noise: jax.Array | None = None) -> jax.Array | tuple[jax.Array, jax.Array]:
        """`embedding_noise` (`[..., embed]`, FCA-IB's bottleneck sample) is added to the embedding before the
        head reads it; the embedding returned is the layer's output without it. Both outputs float32."""
        dense = lambda n, name: nn.Dense(n, kernel_init=INITS[self.weights_init], dtype=self.dtype,  # noqa: E731
                                         name=name)
        z = dense(self.embed, "embedding")(features)
        h = z if embedding_noise is None else z + embedding_noise.astype(z.dtype)
        h = _lrelu(h) if self.activate_embedding else h
        action = _out(dense(self.action_dim, "action")(_lrelu(dense(self.hidden, "head")(h))))
        return (action, _out(z)) if return_embedding else action


class StatePolicy(nn.Module):
    """`[..., H * D]` stacked state observations -> `[..., A]` action.

    `batchnorm=True`: the FCA code's network (module docstring). `train=True` normalises each encoder layer by
    the batch's statistics and updates the running ones (`mutable=["batch_stats"]`); `train=False` (every use
    but a training step) uses the running statistics. Without BatchNorm `train` changes nothing. Leading
    dimensions are flattened for BatchNorm, whose statistics are over all of them.

    `first_layer_input` (`[..., hidden[0]]`) is added to the first encoder layer's pre-activation (before its
    BatchNorm): a second input block of that layer, projected by the caller (PrimeNet's prime,
    `ape_jax.baselines.priming`). A layer on `[x, p]` is `x K_x + p K_p`, so this is concatenation with the
    kernel split in two; a zero block leaves the network's function and gradients exactly as without it.
    """

    action_dim: int
    hidden: Sequence[int] = (300, 300, 300)
    batchnorm: bool = False
    weights_init: str = "lecun"
    bn_momentum: float = 0.1
    dtype: str = "float32"

    @nn.compact
    def __call__(self, obs: jax.Array, return_embedding: bool = False, train: bool = False,
                 embedding_noise: jax.Array | None = None, first_layer_input: jax.Array | None = None
                 ) -> jax.Array | tuple[jax.Array, jax.Array]:
        lead = obs.shape[:-1]
        x = obs.reshape((-1, obs.shape[-1])) if self.batchnorm else obs
        for i, width in enumerate(self.hidden):
            x = nn.Dense(width, use_bias=not self.batchnorm, kernel_init=INITS[self.weights_init], dtype=self.dtype,
                         name=f"encoder_{i}")(x)
            if i == 0 and first_layer_input is not None:
                extra = first_layer_input.astype(x.dtype)
                x = x + (extra.reshape((-1, extra.shape[-1])) if self.batchnorm else extra)
            if self.batchnorm:
                # Flax's momentum is the old statistics' share: PyTorch's 0.1 is Flax's 0.9
                x = nn.BatchNorm(use_running_average=not train, momentum=1.0 - self.bn_momentum, epsilon=1e-5,
                                 scale_init=_bn_scale_init, dtype=self.dtype, name=f"norm_{i}")(x)
            x = _lrelu(x)
        if self.batchnorm:
            x = x.reshape(lead + x.shape[-1:])
        return Head(self.action_dim, weights_init=self.weights_init, activate_embedding=self.batchnorm,
                    dtype=self.dtype)(x, return_embedding, embedding_noise)


NORMS = ("none", "group")  # the CPU image encoders' normalisation after each layer (`encoder_norm`)
GROUPS = 8  # GroupNorm's groups (channels per group: 4 of 32, 8 of 64)


def encoder_norm(kind: str, name: str, dtype: str = "float32"):
    """The layer `kind` (`NORMS`) puts after an image encoder's layer, before its activation: GroupNorm over
    `GROUPS` groups of channels (per sample: the same in training and evaluation, in a scan or a vmap), or
    nothing. Its statistics are computed in float32 whatever `dtype` (Flax's norms do so)."""
    if kind == "group":
        # statistics over each sample's [height, width, channels] alone, whatever leading dims it has
        return nn.GroupNorm(num_groups=GROUPS, epsilon=1e-5, reduction_axes=(-3, -2, -1), dtype=dtype, name=name)
    return lambda x: x


class ImagePolicy(nn.Module):
    """`[..., height, width, 3 * H]` stacked frames in [0, 1] -> `[..., A]` action.

    `norm="group"`: GroupNorm after each convolution (`encoder_norm`)."""

    action_dim: int
    channels: Sequence[int] = (32, 64, 64)
    norm: str = "none"
    dtype: str = "float32"
    min_side: ClassVar[int] = 1  # the smallest image side it takes (`SAME` padding: any)
    # XLA:CPU runs these convolutions' gradients ~50x slower inside a loop and ~2x slower per model under vmap
    # (`ape_jax.pipeline.training.CPU_IMAGE_CHUNK`): on a CPU the sweep trains it unrolled, one model at a time
    loop_friendly: ClassVar[bool] = False

    @nn.compact
    def __call__(self, frames: jax.Array, return_embedding: bool = False,
                 embedding_noise: jax.Array | None = None) -> jax.Array | tuple[jax.Array, jax.Array]:
        x = frames.astype(self.dtype)
        for i, c in enumerate(self.channels):
            x = nn.Conv(c, (5, 5) if i == 0 else (3, 3), strides=2, dtype=self.dtype, name=f"conv_{i}")(x)
            x = _lrelu(encoder_norm(self.norm, f"norm_{i}", self.dtype)(x))
        return Head(self.action_dim, dtype=self.dtype)(x.reshape(x.shape[:-3] + (-1,)), return_embedding,
                                                       embedding_noise)


class PatchPolicy(nn.Module):
    """`[..., height, width, 3 * H]` stacked frames in [0, 1] -> `[..., A]` action, through a patch embedding.

    The encoder built for XLA:CPU (`IMAGE_ENCODERS["patch"]`): the frames are cut into
    non-overlapping 8×8 patches (`patchify`), each patch (8·8·3H values) goes through one
    `Dense` to 64 features and LeakyReLU(0.2) — a convolution with kernel = stride = 8 —
    and the `[h/8, w/8, 64]` grid is flattened into the same `Head` as `ImagePolicy`.
    At 32×32 that is a 4×4×64 grid, as `ImagePolicy`'s last convolution gives, and
    158k parameters against its 194k (history 2).

    Why: on a CPU a training step's time follows its FLOPs. `ImagePolicy`'s three
    overlapping convolutions cost ~1 GMAC per update at 32×32, batch 128 (forward,
    weight and input gradients), this ~0.15 GMAC; measured in one process on a 2-core
    AMD EPYC it trains ~5× as many model-updates/s. It is matrix products only, so it
    trains as fast inside `lax.scan` and under `vmap` as unrolled and one model at a time
    (`loop_friendly`; `ImagePolicy`'s convolution gradients run ~40× slower in a scan and
    ~2× slower per model vmapped), and the sweep trains its grid like the state policies'.
    Per update it learns more slowly than `ImagePolicy` at the same learning rate (Hopper,
    32×32: a higher validation loss after the same updates, a lower one after the same
    CPU time); `experiments.bench_images` measures the speed.

    `patches` and `channels` (one layer per entry, each on the previous layer's grid)
    stay configurable for experiments; sides that a patch does not divide are zero-padded.
    `norm="group"`: GroupNorm after each patch layer (`encoder_norm`).
    """

    action_dim: int
    patches: Sequence[int] = (8,)
    channels: Sequence[int] = (64,)
    norm: str = "none"
    dtype: str = "float32"
    min_side: ClassVar[int] = 1  # a side that a patch does not divide is padded
    # trains as fast inside `lax.scan` and under `vmap` as outside them on XLA:CPU (matrix products only)
    loop_friendly: ClassVar[bool] = True

    @nn.compact
    def __call__(self, frames: jax.Array, return_embedding: bool = False,
                 embedding_noise: jax.Array | None = None) -> jax.Array | tuple[jax.Array, jax.Array]:
        x = frames.astype(self.dtype)
        for i, (p, c) in enumerate(zip(self.patches, self.channels, strict=True)):
            x = nn.Dense(c, dtype=self.dtype, name=f"patch_{i}")(patchify(x, p))
            x = _lrelu(encoder_norm(self.norm, f"norm_{i}", self.dtype)(x))
        return Head(self.action_dim, dtype=self.dtype)(x.reshape(x.shape[:-3] + (-1,)), return_embedding,
                                                       embedding_noise)


def windows3x3(x: jax.Array, stride: int) -> jax.Array:
    """`[..., h, w, C]` -> `[..., h', w', 9·C]`: every 3×3 window of a `VALID` convolution of `stride`, flattened.

    `h' = ⌊(h − 3) / stride⌋ + 1` (likewise `w'`). Each window's values are in `(row, column, channel)` order, so
    a matrix product with a `[3, 3, C, C']` kernel reshaped to `[9·C, C']` is that convolution (im2col). Built from
    nine strided slices: its gradient is padding and adding, no convolution.
    """
    h, w = x.shape[-3], x.shape[-2]
    ho, wo = (h - 3) // stride + 1, (w - 3) // stride + 1
    cols = [x[..., i:i + stride * (ho - 1) + 1:stride, j:j + stride * (wo - 1) + 1:stride, :]
            for i in range(3) for j in range(3)]
    return jnp.concatenate(cols, axis=-1)


class Conv3x3(nn.Module):
    """A 3×3 `VALID` convolution `[..., h, w, C]` -> `[..., h', w', features]`, with bias.

    `matmul=True` computes it as a matrix product over `windows3x3` (im2col); `False` as XLA's convolution
    (`lax.conv_general_dilated`). The parameters (`kernel [3, 3, C, features]`, `bias [features]`) and the
    result are the same; the speed is not (`DrQPolicy`). Kernels orthogonal with ReLU's gain √2, as DrQ-v2
    initialises its convolutions; biases zero.
    """

    features: int
    stride: int = 1
    matmul: bool = True
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = self.param("kernel", nn.initializers.orthogonal(2.0 ** 0.5), (3, 3, x.shape[-1], self.features))
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        x, kernel, bias = (a.astype(self.dtype) for a in (x, kernel, bias))
        if self.matmul:
            return windows3x3(x, self.stride) @ kernel.reshape(-1, self.features) + bias
        lead = x.shape[:-3]
        y = jax.lax.conv_general_dilated(x.reshape((-1,) + x.shape[-3:]), kernel, (self.stride, self.stride),
                                         "VALID", dimension_numbers=("NHWC", "HWIO", "NHWC"))
        return y.reshape(lead + y.shape[-3:]) + bias


class DrQPolicy(nn.Module):
    """`[..., height, width, 3 * H]` stacked frames in [0, 1] -> `[..., A]` action, through DrQ's encoder.

    The pixel encoder of image-based continuous control since DrQ (Kostrikov, Yarats and Fergus, 2020) and
    DrQ-v2 (Yarats et al., 2021), written from the papers' description: the frames centred (`x − 0.5`), four 3×3
    convolutions of 32 channels without padding, the first of stride 2, each followed by ReLU; the `[h', w', 32]`
    map flattened into the project's `Head` (DrQ-v2's own 50-unit LayerNorm-tanh trunk is the actor's, which
    here is the `Head`'s 100-unit embedding). At 84×84 the map is 35×35×32 (39,200 features), so the `Head`'s
    first matrix holds 3.9M of the policy's 4.0M parameters; the history's frames are stacked on channels
    (DrQ's frame stacking). Random shift (DrQ's ±4 pixels at 84×84) is the recipe's `augment_shift`.

    The smallest side it takes is `min_side` = 15: the three unstrided convolutions need a 7×7 map, which the
    strided one gives from `2·(7 − 1) + 3` pixels.

    Why im2col (`Conv3x3`, `matmul=True`): XLA:CPU runs convolution gradients inside `lax.scan` tens of times
    slower than outside it (`ImagePolicy`); as matrix products the encoder trains as fast in a scan and under
    `vmap` (`loop_friendly`), so the sweep trains its grid like the patch encoder's. `matmul=False` is XLA's
    convolution, the same function (a test checks it). `norm="group"`: GroupNorm after each convolution.
    """

    action_dim: int
    channels: int = 32
    layers: int = 4
    norm: str = "none"
    dtype: str = "float32"
    matmul: bool = True
    loop_friendly: ClassVar[bool] = True  # matrix products only (`matmul=True`)
    min_side: ClassVar[int] = 2 * (2 * (4 - 1)) + 3  # 15: `layers` − 1 unstrided 3×3 convs need 2·3 + 1 pixels

    @nn.compact
    def __call__(self, frames: jax.Array, return_embedding: bool = False,
                 embedding_noise: jax.Array | None = None) -> jax.Array | tuple[jax.Array, jax.Array]:
        x = frames.astype(self.dtype) - 0.5
        for i in range(self.layers):
            x = Conv3x3(self.channels, 2 if i == 0 else 1, self.matmul, self.dtype, name=f"conv_{i}")(x)
            x = nn.relu(encoder_norm(self.norm, f"norm_{i}", self.dtype)(x))
        return Head(self.action_dim, dtype=self.dtype)(x.reshape(x.shape[:-3] + (-1,)), return_embedding,
                                                       embedding_noise)


# He (Kaiming) normal init, fan-out, as is usual for ReLU ResNets; the convolutions
# have no bias since a normalisation with its own bias follows each of them.
_conv_init = nn.initializers.variance_scaling(2.0, "fan_out", "normal")


def _group_norm(channels: int, name: str, dtype: str) -> nn.GroupNorm:
    return nn.GroupNorm(num_groups=min(32, channels), epsilon=1e-5, dtype=dtype, name=name)


class BasicBlock(nn.Module):
    """ResNet's basic block: `3×3 conv (stride) → GN → ReLU → 3×3 conv → GN`, plus the shortcut, then ReLU.

    The shortcut is the identity, or a `1×1 conv (stride) → GN` projection when
    the stride or the channel count changes. Input and output `[N, h, w, C]`.
    """

    channels: int
    strides: int = 1
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        y = nn.Conv(self.channels, (3, 3), self.strides, padding=((1, 1), (1, 1)), use_bias=False,
                    kernel_init=_conv_init, dtype=self.dtype, name="conv_0")(x)
        y = nn.relu(_group_norm(self.channels, "norm_0", self.dtype)(y))
        y = nn.Conv(self.channels, (3, 3), padding=((1, 1), (1, 1)), use_bias=False,
                    kernel_init=_conv_init, dtype=self.dtype, name="conv_1")(y)
        y = _group_norm(self.channels, "norm_1", self.dtype)(y)
        if self.strides != 1 or x.shape[-1] != self.channels:
            x = nn.Conv(self.channels, (1, 1), self.strides, padding="VALID", use_bias=False,
                        kernel_init=_conv_init, dtype=self.dtype, name="shortcut_conv")(x)
            x = _group_norm(self.channels, "shortcut_norm", self.dtype)(x)
        return nn.relu(x + y)


class ResNet18Encoder(nn.Module):
    """ResNet-18 without its classifier: `[N, height, width, C]` -> `[N, 512]` globally average-pooled features.

    `7×7/2 conv 64 → GN → ReLU → 3×3/2 max-pool`, four stages of two `BasicBlock`s
    with 64, 128, 256, 512 channels (stride 2 at the start of stages 2–4), global
    average pool. Paddings as in the original (3 for the 7×7 conv, 1 for the pool
    and the 3×3 convs), so a 64×64 input reaches stage 4 at 2×2. Any `C`: the
    first convolution takes all input channels (3·H for H stacked frames).
    """

    stage_channels: Sequence[int] = (64, 128, 256, 512)
    blocks_per_stage: int = 2
    dtype: str = "float32"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.Conv(self.stage_channels[0], (7, 7), 2, padding=((3, 3), (3, 3)), use_bias=False,
                    kernel_init=_conv_init, dtype=self.dtype, name="stem_conv")(x.astype(self.dtype))
        x = nn.relu(_group_norm(self.stage_channels[0], "stem_norm", self.dtype)(x))
        x = nn.max_pool(x, (3, 3), strides=(2, 2), padding=((1, 1), (1, 1)))
        for s, c in enumerate(self.stage_channels):
            for b in range(self.blocks_per_stage):
                x = BasicBlock(c, strides=2 if s > 0 and b == 0 else 1, dtype=self.dtype,
                               name=f"stage{s + 1}_block{b}")(x)
        return x.mean(axis=(-3, -2))


class ResNet18Policy(nn.Module):
    """`[..., height, width, 3 * H]` stacked frames in [0, 1] -> `[..., A]` action, through ResNet-18.

    The supplement's MuJoCo-Image network: "ResNet-18 with a two-layer 300-unit
    MLP head", trained from scratch. Our readings:

    - **History.** The supplement does not say how the H frames enter the
      network; we stack them on channels (early fusion) like `ImagePolicy`, so
      only the first convolution changes: `7·7·(3H)·64` weights instead of
      `7·7·3·64`. Everything after it is the standard ResNet-18.
    - **Head.** The two 300-unit hidden layers, with the project's 100-unit
      linear `embedding` (FCA's adversary reads it) between them:
      `512 → Dense 300 → LReLU → Head (embedding 100 → 300 → LReLU → action)`.
      The 100-unit layer is linear, so the head is the paper's two-layer MLP
      with its 300×300 middle matrix factored through rank 100.
    - **Normalisation: GroupNorm, not BatchNorm** (`min(32, C)` groups: 2–16
      channels per group here). The learners can carry BatchNorm's running
      statistics (the state recipe `fca` does, `StatePolicy(batchnorm=True)`,
      each configuration of a grid its own), but this network was written
      before they could, and no image recipe has measured BatchNorm against
      GroupNorm here. GroupNorm has the same learnable
      scale and bias, no batch statistics at all (each sample is normalised on
      its own, so training and evaluation compute the same function and the
      batch size is irrelevant), and is the standard BatchNorm replacement for
      small per-model batches (Wu & He, 2018).

    Leading batch dimensions are arbitrary (`[B]`, `[G, B]`, …): they are
    flattened for the convolutions and restored for the head.

    Size and cost: 11.19M encoder parameters with H = 2 (torchvision's
    ResNet-18 without its classifier has 11.18M; GroupNorm has as many as
    BatchNorm), 11.40M in all. A training iteration at batch 128, 64×64, H = 2
    is ~90 GFLOP (XLA's cost estimate), 11× `ImagePolicy`; on a 2-core CPU it
    ran about a hundred times slower than `ImagePolicy` in a one-off probe,
    partly because XLA:CPU is very slow at the 3×3 512-channel convolutions on
    stage 4's 2×2 maps. Meant for GPUs.
    """

    action_dim: int
    hidden: int = 300
    dtype: str = "float32"
    loop_friendly: ClassVar[bool] = False  # convolutions, as `ImagePolicy`
    min_side: ClassVar[int] = 1  # padded convolutions and pools: any side

    @nn.compact
    def __call__(self, frames: jax.Array, return_embedding: bool = False,
                 embedding_noise: jax.Array | None = None) -> jax.Array | tuple[jax.Array, jax.Array]:
        lead = frames.shape[:-3]
        features = ResNet18Encoder(dtype=self.dtype, name="encoder")(frames.reshape((-1,) + frames.shape[-3:]))
        features = features.reshape(lead + features.shape[-1:])
        mlp = nn.Dense(self.hidden, dtype=self.dtype, name="mlp")
        return Head(self.action_dim, hidden=self.hidden, dtype=self.dtype)(_lrelu(mlp(features)), return_embedding,
                                                                           embedding_noise)


class PerceptionPolicy(nn.Module):
    """`[..., height, width, 3 * H]` frames in [0, 1] -> `[..., A]` action through a task's pretrained perception
    encoder trained end to end (`recipe.perception_training=finetune`, `ape_jax.perception.tuned`): each frame's
    embedding, then the state policy's network on the `H` embeddings, as the frozen stage's policies are built.
    `dtype` is the head's arithmetic; the pretrained encoder computes in float32."""

    action_dim: int
    sha256: str = ""       # the encoder file's (`recipe.perception_sha256`)
    norm: str = "none"     # the pixel encoders' option; the pretrained network has none
    dtype: str = "float32"
    loop_friendly: ClassVar[bool] = True  # matrix products only (`PerceptionNet`'s patch stack)
    min_side: ClassVar[int] = 1  # the file's image size is checked when the settings are resolved

    @nn.compact
    def __call__(self, frames: jax.Array, return_embedding: bool = False,
                 embedding_noise: jax.Array | None = None) -> jax.Array | tuple[jax.Array, jax.Array]:
        from ape_jax.perception.tuned import PretrainedEncoder

        features = PretrainedEncoder(self.sha256, name="perception")(frames)
        return StatePolicy(self.action_dim, dtype=self.dtype, name="policy")(
            features, return_embedding, embedding_noise=embedding_noise)


# `LearnerConfig.encoder` -> the image policy it builds.
IMAGE_ENCODERS: dict[str, type[nn.Module]] = {"small": ImagePolicy, "resnet18": ResNet18Policy,
                                               "patch": PatchPolicy, "drq": DrQPolicy,
                                               "perception": PerceptionPolicy}
