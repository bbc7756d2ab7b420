"""Non-overlapping patches of an image: the matrix-product form of a convolution whose kernel equals its stride,
shared by the patch policy (`ape_jax.models.PatchPolicy`) and the perception network (`ape_jax.perception.net`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def patchify(x: jax.Array, patch: int) -> jax.Array:
    """`[..., h, w, C]` -> `[..., ⌈h/p⌉, ⌈w/p⌉, p·p·C]`: non-overlapping `p×p` patches, each flattened.

    A side that `patch` does not divide is zero-padded at its end first (as a `SAME`
    convolution of stride `p` would). Each patch's values are in `(row, column, channel)`
    order, so a `Dense` on the last axis is a `p×p` convolution of stride `p`.
    """
    *lead, h, w, c = x.shape
    pad_h, pad_w = -h % patch, -w % patch
    if pad_h or pad_w:
        x = jnp.pad(x, [(0, 0)] * len(lead) + [(0, pad_h), (0, pad_w), (0, 0)])
        h, w = h + pad_h, w + pad_w
    x = x.reshape(*lead, h // patch, patch, w // patch, patch, c)
    x = jnp.swapaxes(x, -4, -3)  # [..., h/p, w/p, p, p, C]
    return x.reshape(*lead, h // patch, w // patch, patch * patch * c)
