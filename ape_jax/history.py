"""Observation and action histories by index: the one place episode starts are padded.

A dataset is rows grouped by episode with time index `t = 0, 1, 2, …`; a
history is built at batch time from row indices, never by copying frames, so
it costs nothing in memory and runs inside `jit`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def history_index(t: jax.Array, idx: jax.Array, length: int, offset: int = 0) -> jax.Array:
    """Row indices of the `length` steps ending `offset` steps before each row in `idx`.

    Rows before the episode's first step are replaced by the first step, so a
    history at an episode start repeats the first observation (or action).

    Args:
      t: time indices of the dataset, `[N] int32`.
      idx: rows, `[B] int32`.
      length: history length `H`.
      offset: 0 for observation histories ending at the row itself; 1 for
        "the previous `H` actions".

    Returns:
      `[B, H] int32`, oldest first.
    """
    idx = jnp.asarray(idx)
    start = idx - jnp.asarray(t)[idx]
    back = jnp.arange(length - 1 + offset, offset - 1, -1)
    return jnp.maximum(idx[:, None] - back[None, :], start[:, None])
