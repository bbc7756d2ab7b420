"""The perception stage's network: a patch stack that reads one frame, and the embedding every method trains on.

    net = PerceptionNet(targets=20)
    y = net.apply(params, frames)                       # [..., 20] the targets, standardised
    y, e = net.apply(params, frames, return_embedding=True)   # e: [..., 128] the embedding
    embed = embedder(encoder)                           # jit-able: [..., H, W, 3] uint8 -> [..., E] float32

Built for XLA:CPU as the patch policy is (`ape_jax.models.PatchPolicy`, docs/speed.md): each stage cuts its input
into non-overlapping `p×p` patches and maps each through one `Dense` (a convolution with kernel = stride = p, as a
matrix product), twice (`patches=(4, 4)`: 64×64 → 16×16×32 → 4×4×128), then two dense layers to the embedding
(GELU throughout) and a linear read-out of the targets. Dense products run near the CPU's matmul peak; convolution
gradients do not.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from ape_jax.patches import patchify


class PerceptionNet(nn.Module):
    """`[..., H, W, 3]` uint8 frames -> `[..., targets]` (and the `[..., embedding]` features before the read-out).

    Attributes:
      targets: the number of one-frame targets read out (standardised).
      patches, channels: one patch layer per entry (`models.patchify`), each on the previous layer's grid.
      hidden: the dense layer between the patch grid and the embedding.
      embedding: the embedding's width (what a policy sees of one frame).
    """

    targets: int
    patches: Sequence[int] = (4, 4)
    channels: Sequence[int] = (32, 128)
    hidden: int = 256
    embedding: int = 128

    @nn.compact
    def __call__(self, frames: jax.Array, return_embedding: bool = False):
        x = frames.astype(jnp.float32) / 255.0
        for i, (p, c) in enumerate(zip(self.patches, self.channels, strict=True)):
            x = nn.gelu(nn.Dense(c, name=f"patch_{i}")(patchify(x, p)))
        x = x.reshape(*x.shape[:-3], -1)
        x = nn.gelu(nn.Dense(self.hidden, name="hidden")(x))
        e = nn.gelu(nn.Dense(self.embedding, name="embedding")(x))
        y = nn.Dense(self.targets, name="readout")(e)
        return (y, e) if return_embedding else y


def net_of(spec: dict) -> PerceptionNet:
    """The network a card's `net` block describes (`{"targets", "patches", "channels", "hidden", "embedding"}`)."""
    return PerceptionNet(targets=int(spec["targets"]), patches=tuple(spec["patches"]),
                         channels=tuple(spec["channels"]), hidden=int(spec["hidden"]),
                         embedding=int(spec["embedding"]))


def net_spec(net: PerceptionNet) -> dict:
    """`net_of`'s inverse: the JSON a card records of `net`."""
    return {"targets": net.targets, "patches": list(net.patches), "channels": list(net.channels),
            "hidden": net.hidden, "embedding": net.embedding}


def embedder(net: PerceptionNet, params: Any) -> Callable[[jax.Array], jax.Array]:
    """`frames [..., H, W, 3] uint8 -> [..., E] float32`: the frozen encoder's embedding (jit-able, no gradient)."""
    frozen = jax.lax.stop_gradient(params)
    return lambda frames: net.apply(frozen, frames, return_embedding=True)[1]


def near(values: np.ndarray, scale: float) -> np.ndarray:
    """A distance as the encoder regresses it (`tasks.Perception.near`): `exp(−x / scale)`, steep up close."""
    return np.exp(-np.asarray(values, np.float32) / scale)


def far(values: jax.Array, scale: float) -> jax.Array:
    """`near`'s inverse, `−scale · log(y)`, `y` clipped into (0, 1]."""
    return -scale * jnp.log(jnp.clip(values, 1e-6, 1.0))


def reader(net: PerceptionNet, params: Any, mean, std, near_scales: Sequence[float | None] = ()
           ) -> Callable[[jax.Array], jax.Array]:
    """`frames [..., H, W, 3] uint8 -> [..., D] float32`: the frozen encoder's read-out of its targets, in their own
    units (`mean`, `std`: the card's standardisation; `near_scales`: per target, the `near` transform's scale to
    invert, None where it has none): the one-frame state as the encoder reads it."""
    frozen = jax.lax.stop_gradient(params)
    mean, std = jnp.asarray(mean, jnp.float32), jnp.asarray(std, jnp.float32)
    scales = list(near_scales) or [None] * len(mean)

    def read(frames):
        y = net.apply(frozen, frames) * std + mean
        cols = [far(y[..., i], s) if s else y[..., i] for i, s in enumerate(scales)]
        return jnp.stack(cols, axis=-1)

    return read


def in_chunks(fn: Callable[[jax.Array], jax.Array], frames: np.ndarray, chunk: int = 4096,
              progress: Callable[[int], None] | None = None) -> np.ndarray:
    """`fn` (a batched `[B, ...] -> [B, ...]` function) over `frames` `[N, ...]`, `chunk` rows per jitted call (the
    last padded: one compiled program), gathered on the host as float32."""
    n = len(frames)
    if n == 0:
        raise ValueError("no frames to embed")
    chunk = min(chunk, n)
    run = jax.jit(fn)
    out = None
    for start in range(0, n, chunk):
        idx = np.minimum(np.arange(start, start + chunk), n - 1)
        part = np.asarray(run(np.asarray(frames[idx])), np.float32)[: n - start]
        if out is None:
            out = np.empty((n, *part.shape[1:]), np.float32)
        out[start:start + len(part)] = part
        if progress:
            progress(min(start + chunk, n))
    return out
