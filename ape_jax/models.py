"""Policies: observation history -> action.

- `StatePolicy` — for state observations, in the style of the copycat paper's
  network: three hidden layers of 300, a 100-unit embedding, a 300-unit head,
  LeakyReLU(0.2). Input: the last `H` observations, flattened `[..., H * D]`.
- `ImagePolicy` — for images: a small conv encoder (CPU-sized) to the same
  100-unit embedding and head. Input: the last `H` frames stacked on channels,
  `[..., height, width, 3 * H]`, already scaled to [0, 1].

Both take `return_embedding=True` to return `(action, embedding)`, the
embedding being the Head's 100-unit `embedding` layer (for FCA's adversary);
the parameters are the same either way.
"""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax


def _lrelu(x: jax.Array) -> jax.Array:
    return nn.leaky_relu(x, negative_slope=0.2)


class Head(nn.Module):
    """Embedding (100) -> 300 -> action."""

    action_dim: int
    embed: int = 100
    hidden: int = 300

    @nn.compact
    def __call__(self, features: jax.Array, return_embedding: bool = False) -> jax.Array | tuple[jax.Array, jax.Array]:
        z = nn.Dense(self.embed, name="embedding")(features)
        action = nn.Dense(self.action_dim, name="action")(_lrelu(nn.Dense(self.hidden, name="head")(z)))
        return (action, z) if return_embedding else action


class StatePolicy(nn.Module):
    """`[..., H * D]` stacked state observations -> `[..., A]` action."""

    action_dim: int
    hidden: Sequence[int] = (300, 300, 300)

    @nn.compact
    def __call__(self, obs: jax.Array, return_embedding: bool = False) -> jax.Array | tuple[jax.Array, jax.Array]:
        x = obs
        for i, width in enumerate(self.hidden):
            x = _lrelu(nn.Dense(width, name=f"encoder_{i}")(x))
        return Head(self.action_dim)(x, return_embedding)


class ImagePolicy(nn.Module):
    """`[..., height, width, 3 * H]` stacked frames in [0, 1] -> `[..., A]` action."""

    action_dim: int
    channels: Sequence[int] = (32, 64, 64)

    @nn.compact
    def __call__(self, frames: jax.Array, return_embedding: bool = False) -> jax.Array | tuple[jax.Array, jax.Array]:
        x = frames
        for i, c in enumerate(self.channels):
            x = _lrelu(nn.Conv(c, (5, 5) if i == 0 else (3, 3), strides=2, name=f"conv_{i}")(x))
        return Head(self.action_dim)(x.reshape(x.shape[:-3] + (-1,)), return_embedding)
