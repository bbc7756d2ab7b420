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

- `ResNet18Policy` — for images on a GPU: the supplement's MuJoCo-Image
  network, "ResNet-18 with a two-layer 300-unit MLP head" (details and our
  readings in its docstring). Same input as `ImagePolicy`.

All take `return_embedding=True` to return `(action, embedding)`, the
embedding being the Head's 100-unit `embedding` layer (for FCA's adversary);
the parameters are the same either way.
"""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp


def _lrelu(x: jax.Array) -> jax.Array:
    return nn.leaky_relu(x, negative_slope=0.2)


# Dense kernel initialisers by name: Flax's default (LeCun normal) and the FCA code's (xavier uniform).
INITS = {"lecun": nn.initializers.lecun_normal(), "xavier": nn.initializers.xavier_uniform()}


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

    @nn.compact
    def __call__(self, features: jax.Array, return_embedding: bool = False,
                 embedding_noise: jax.Array | None = None) -> jax.Array | tuple[jax.Array, jax.Array]:
        """`embedding_noise` (`[..., embed]`, FCA-IB's bottleneck sample) is added to the embedding before the
        head reads it; the embedding returned is the layer's output without it."""
        dense = lambda n, name: nn.Dense(n, kernel_init=INITS[self.weights_init], name=name)  # noqa: E731
        z = dense(self.embed, "embedding")(features)
        h = z if embedding_noise is None else z + embedding_noise
        h = _lrelu(h) if self.activate_embedding else h
        action = dense(self.action_dim, "action")(_lrelu(dense(self.hidden, "head")(h)))
        return (action, z) if return_embedding else action


class StatePolicy(nn.Module):
    """`[..., H * D]` stacked state observations -> `[..., A]` action.

    `batchnorm=True`: the FCA code's network (module docstring). `train=True` normalises each encoder layer by
    the batch's statistics and updates the running ones (`mutable=["batch_stats"]`); `train=False` (every use
    but a training step) uses the running statistics. Without BatchNorm `train` changes nothing. Leading
    dimensions are flattened for BatchNorm, whose statistics are over all of them.
    """

    action_dim: int
    hidden: Sequence[int] = (300, 300, 300)
    batchnorm: bool = False
    weights_init: str = "lecun"
    bn_momentum: float = 0.1

    @nn.compact
    def __call__(self, obs: jax.Array, return_embedding: bool = False, train: bool = False,
                 embedding_noise: jax.Array | None = None) -> jax.Array | tuple[jax.Array, jax.Array]:
        lead = obs.shape[:-1]
        x = obs.reshape((-1, obs.shape[-1])) if self.batchnorm else obs
        for i, width in enumerate(self.hidden):
            x = nn.Dense(width, use_bias=not self.batchnorm, kernel_init=INITS[self.weights_init],
                         name=f"encoder_{i}")(x)
            if self.batchnorm:
                # Flax's momentum is the old statistics' share: PyTorch's 0.1 is Flax's 0.9
                x = nn.BatchNorm(use_running_average=not train, momentum=1.0 - self.bn_momentum, epsilon=1e-5,
                                 scale_init=_bn_scale_init, name=f"norm_{i}")(x)
            x = _lrelu(x)
        if self.batchnorm:
            x = x.reshape(lead + x.shape[-1:])
        return Head(self.action_dim, weights_init=self.weights_init, activate_embedding=self.batchnorm)(
            x, return_embedding, embedding_noise)


class ImagePolicy(nn.Module):
    """`[..., height, width, 3 * H]` stacked frames in [0, 1] -> `[..., A]` action."""

    action_dim: int
    channels: Sequence[int] = (32, 64, 64)

    @nn.compact
    def __call__(self, frames: jax.Array, return_embedding: bool = False,
                 embedding_noise: jax.Array | None = None) -> jax.Array | tuple[jax.Array, jax.Array]:
        x = frames
        for i, c in enumerate(self.channels):
            x = _lrelu(nn.Conv(c, (5, 5) if i == 0 else (3, 3), strides=2, name=f"conv_{i}")(x))
        return Head(self.action_dim)(x.reshape(x.shape[:-3] + (-1,)), return_embedding, embedding_noise)


# He (Kaiming) normal init, fan-out, as is usual for ReLU ResNets; the convolutions
# have no bias since a normalisation with its own bias follows each of them.
_conv_init = nn.initializers.variance_scaling(2.0, "fan_out", "normal")


def _group_norm(channels: int, name: str) -> nn.GroupNorm:
    return nn.GroupNorm(num_groups=min(32, channels), epsilon=1e-5, name=name)


class BasicBlock(nn.Module):
    """ResNet's basic block: `3×3 conv (stride) → GN → ReLU → 3×3 conv → GN`, plus the shortcut, then ReLU.

    The shortcut is the identity, or a `1×1 conv (stride) → GN` projection when
    the stride or the channel count changes. Input and output `[N, h, w, C]`.
    """

    channels: int
    strides: int = 1

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        y = nn.Conv(self.channels, (3, 3), self.strides, padding=((1, 1), (1, 1)), use_bias=False,
                    kernel_init=_conv_init, name="conv_0")(x)
        y = nn.relu(_group_norm(self.channels, "norm_0")(y))
        y = nn.Conv(self.channels, (3, 3), padding=((1, 1), (1, 1)), use_bias=False,
                    kernel_init=_conv_init, name="conv_1")(y)
        y = _group_norm(self.channels, "norm_1")(y)
        if self.strides != 1 or x.shape[-1] != self.channels:
            x = nn.Conv(self.channels, (1, 1), self.strides, padding="VALID", use_bias=False,
                        kernel_init=_conv_init, name="shortcut_conv")(x)
            x = _group_norm(self.channels, "shortcut_norm")(x)
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

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.Conv(self.stage_channels[0], (7, 7), 2, padding=((3, 3), (3, 3)), use_bias=False,
                    kernel_init=_conv_init, name="stem_conv")(x)
        x = nn.relu(_group_norm(self.stage_channels[0], "stem_norm")(x))
        x = nn.max_pool(x, (3, 3), strides=(2, 2), padding=((1, 1), (1, 1)))
        for s, c in enumerate(self.stage_channels):
            for b in range(self.blocks_per_stage):
                x = BasicBlock(c, strides=2 if s > 0 and b == 0 else 1, name=f"stage{s + 1}_block{b}")(x)
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

    @nn.compact
    def __call__(self, frames: jax.Array, return_embedding: bool = False,
                 embedding_noise: jax.Array | None = None) -> jax.Array | tuple[jax.Array, jax.Array]:
        lead = frames.shape[:-3]
        features = ResNet18Encoder(name="encoder")(frames.reshape((-1,) + frames.shape[-3:]))
        features = features.reshape(lead + features.shape[-1:])
        return Head(self.action_dim, hidden=self.hidden)(_lrelu(nn.Dense(self.hidden, name="mlp")(features)),
                                                         return_embedding, embedding_noise)


# `LearnerConfig.encoder` -> the image policy it builds.
IMAGE_ENCODERS: dict[str, type[nn.Module]] = {"small": ImagePolicy, "resnet18": ResNet18Policy}
