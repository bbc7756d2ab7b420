"""Observation and action histories by index: the one place episode starts (and, for targets that look ahead,
episode ends) are padded.

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


def future_index(t: jax.Array, idx: jax.Array, length: int) -> jax.Array:
    """Row indices of the `length` steps starting at each row in `idx`, the episode's last step repeated past its end.

    The mirror of `history_index` for targets that look ahead (action chunks): episodes are contiguous rows with
    `t = 0, 1, …`, so row `idx + j` belongs to `idx`'s episode exactly when it exists and its `t` is `t[idx] + j`;
    from the first `j` where that fails every later step reads the episode's last row.

    Args:
      t: time indices of the dataset, `[N] int32`.
      idx: rows, `[B] int32`.
      length: steps ahead `k`, the row itself included.

    Returns:
      `[B, k] int32`, the row itself first.
    """
    t, idx = jnp.asarray(t), jnp.asarray(idx)
    ahead = jnp.arange(length)
    rows = jnp.minimum(idx[:, None] + ahead[None, :], t.shape[0] - 1)
    same = (t[rows] == t[idx][:, None] + ahead[None, :]) & (idx[:, None] + ahead[None, :] < t.shape[0])
    steps = jnp.sum(jnp.cumprod(same.astype(jnp.int32), axis=1), axis=1)  # rows left in the episode, its own included
    return idx[:, None] + jnp.minimum(ahead[None, :], steps[:, None] - 1)
