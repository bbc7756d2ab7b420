"""Inverse action-frequency weights (ActFreq): rare actions count more.

Each action dimension `d` is cut into `bins` equal-width bins between its
minimum and maximum over the given set, with edges

    e_{d,k} = min_d + k · (max_d − min_d) / bins,    k = 0, ..., bins,

bin `k` holding `e_{d,k} ≤ a_d < e_{d,k+1}` (the last bin also holds `max_d`;
a constant dimension has a single bin). A sample's bin is the tuple of its
per-dimension bins, one of up to `bins^A` joint bins. With `n_b` the number of
samples in joint bin `b` and `K` the number of non-empty joint bins,

    w_i ∝ 1 / n_{b(i)},   normalised to mean 1:   w_i = N / (K · n_{b(i)}),

so every non-empty joint bin carries the same total weight `N / K`.

Our reading where the paper leaves details open: `bins = 5` per dimension,
equal-width edges over the training set's own range (no outlier clipping),
joint (not per-dimension) bins, and weights normalised to average exactly 1
over the set they are computed on, like the step and softmax weights.

Computed once before training, in NumPy:

    w = actfreq.weights(train.action)        # [N] float32, mean 1
"""

from __future__ import annotations

import numpy as np

from ape_jax import methods

BINS = 5


def bin_index(actions: np.ndarray, bins: int = BINS) -> np.ndarray:
    """Per-dimension equal-width bin of every action, `[N, A] int64` in `[0, bins)`.

    Args:
      actions: `[N, A]` actions (N >= 1).
      bins: bins per dimension, >= 1.
    """
    actions = np.asarray(actions, np.float64)
    if actions.ndim != 2 or actions.shape[0] == 0:
        raise ValueError(f"actfreq: actions must be [N, A] with N >= 1, got shape {actions.shape}")
    if not (isinstance(bins, (int, np.integer)) and bins >= 1):
        raise ValueError(f"actfreq: bins must be an int >= 1, got {bins!r}")
    if not np.all(np.isfinite(actions)):
        raise ValueError("actfreq: actions must be finite")
    lo, hi = actions.min(axis=0), actions.max(axis=0)
    out = np.empty(actions.shape, np.int64)
    for d in range(actions.shape[1]):
        interior = np.linspace(lo[d], hi[d], bins + 1)[1:-1]
        # A constant dimension has all interior edges equal to its value: one bin.
        out[:, d] = 0 if hi[d] == lo[d] else np.digitize(actions[:, d], interior)
    return out


def weights(actions: np.ndarray, bins: int = BINS) -> np.ndarray:
    """Inverse joint-bin frequency weights, normalised to mean 1.

    Args:
      actions: expert actions, `[N, A] float32`.
      bins: equal-width bins per action dimension, >= 1.

    Returns:
      `[N] float32`: `N / (K · n_{b(i)})`, with `n_b` the count of joint bin `b`
      and `K` the number of non-empty joint bins.
    """
    _, joint, counts = np.unique(bin_index(actions, bins), axis=0, return_inverse=True, return_counts=True)
    joint = joint.reshape(-1)  # NumPy 2.0.x returns it with the input's rank
    n = joint.shape[0]
    return (n / (len(counts) * counts[joint].astype(np.float64))).astype(np.float32)


def _score(key, actions, t):
    return np.asarray(weights(np.asarray(actions)), np.float32)


methods.weighting("actfreq", kind="given", label="ActFreq", role="baseline")(_score)
