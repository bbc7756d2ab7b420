"""k-means category weighting (the paper's supplement §7): small action clusters count more.

The expert's actions are clustered with k-means into `k` categories; with `n_j`
the size of cluster `j` and `c(i)` the cluster of sample `i`, the supplement's
weight is

    w_i = Σ_j n_j / n_{c(i)} = N / n_{c(i)},

which we normalise to average 1 over the set: `w_i = N / (K · n_{c(i)})`, with
`K` the number of non-empty clusters, so every cluster carries the same total
weight `N / K`.

`fit` is plain k-means in JAX: k-means++ initialisation (the first center is a
uniformly drawn sample, each next one a sample drawn with probability ∝ its
squared distance to the nearest center chosen so far), then a fixed number of
Lloyd iterations (assign every sample to its nearest center, ties to the lower
index; move each center to its cluster's mean; an empty cluster keeps its
center). Labels are the final assignment to the returned centers.

Our reading where the paper leaves details open: `k = 6` clusters, 50 Lloyd
iterations, one k-means++ run (no restarts), Euclidean distance on the raw
actions (every action space of the benchmark is a box of comparable range, so
no rescaling), and weights normalised to mean 1 like the step and softmax
weights.

    w = kmeans.weights(key, train.action)        # [N] float32, mean 1
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ape_jax import methods

K = 6
ITERATIONS = 50


def _sq_dist(x: jax.Array, centers: jax.Array) -> jax.Array:
    """Squared Euclidean distances `[N, k]`."""
    return jnp.sum((x[:, None, :] - centers[None, :, :]) ** 2, axis=-1)


@functools.partial(jax.jit, static_argnames=("k", "iterations"))
def fit(key: jax.Array, x: jax.Array, k: int = K, iterations: int = ITERATIONS) -> tuple[jax.Array, jax.Array]:
    """k-means++ initialisation, then `iterations` Lloyd steps.

    Args:
      key: PRNG key (the k-means++ draws).
      x: points, `[N, D] float32`, N >= k.
      k: clusters (static), >= 1.
      iterations: Lloyd iterations (static), >= 0.

    Returns:
      (centers, labels): `[k, D] float32` and each point's nearest center,
      `[N] int32`.
    """
    x = jnp.asarray(x, jnp.float32)
    if x.ndim != 2:
        raise ValueError(f"kmeans.fit: x must be [N, D], got shape {x.shape}")
    if not 1 <= k <= x.shape[0]:
        raise ValueError(f"kmeans.fit: k must be in [1, N = {x.shape[0]}], got {k}")
    if iterations < 0:
        raise ValueError(f"kmeans.fit: iterations must be >= 0, got {iterations}")
    n = x.shape[0]
    key_first, key_rest = jax.random.split(key)

    first = x[jax.random.randint(key_first, (), 0, n)]
    centers = jnp.zeros((k, x.shape[1]), jnp.float32).at[0].set(first)

    def add_center(j, carry):
        centers, d2 = carry                          # d2: squared distance to the nearest chosen center, [N]
        # When every point sits on a chosen center, any point will do.
        weight = jnp.where(jnp.sum(d2) > 0, d2, 1.0)
        c = x[jax.random.categorical(jax.random.fold_in(key_rest, j), jnp.log(weight))]
        return centers.at[j].set(c), jnp.minimum(d2, jnp.sum((x - c) ** 2, axis=-1))

    centers, _ = jax.lax.fori_loop(1, k, add_center, (centers, jnp.sum((x - first) ** 2, axis=-1)))

    def lloyd(_, centers):
        labels = jnp.argmin(_sq_dist(x, centers), axis=1)
        sums = jax.ops.segment_sum(x, labels, num_segments=k)
        counts = jax.ops.segment_sum(jnp.ones(n, jnp.float32), labels, num_segments=k)[:, None]
        return jnp.where(counts > 0, sums / jnp.maximum(counts, 1.0), centers)

    centers = jax.lax.fori_loop(0, iterations, lloyd, centers)
    return centers, jnp.argmin(_sq_dist(x, centers), axis=1).astype(jnp.int32)


def cluster_weights(labels: jax.Array, k: int) -> jax.Array:
    """Inverse cluster-size weights with mean 1.

    Args:
      labels: cluster of every sample, `[N] int32` in `[0, k)`.
      k: number of clusters (static).

    Returns:
      `[N] float32`: `N / (K · n_{c(i)})`, with `n_j` the size of cluster `j`
      and `K` the number of non-empty clusters.
    """
    labels = jnp.asarray(labels)
    if labels.ndim != 1:
        raise ValueError(f"kmeans.cluster_weights: labels must be [N], got shape {labels.shape}")
    sizes = jnp.bincount(labels, length=k).astype(jnp.float32)
    nonempty = jnp.sum(sizes > 0).astype(jnp.float32)
    return labels.shape[0] / (nonempty * sizes[labels])


@functools.partial(jax.jit, static_argnames=("k", "iterations"))
def weights(key: jax.Array, actions: jax.Array, k: int = K, iterations: int = ITERATIONS) -> jax.Array:
    """The supplement's k-means category weights, normalised to mean 1.

    Args:
      key: PRNG key (k-means++ initialisation).
      actions: expert actions, `[N, A] float32`, N >= k.
      k: clusters (static).
      iterations: Lloyd iterations (static).

    Returns:
      `[N] float32`: `N / (K · n_{c(i)})` (see `cluster_weights`).
    """
    _, labels = fit(key, actions, k, iterations)
    return cluster_weights(labels, k)


def _score(key, actions, t):
    return jnp.asarray(weights(key, actions), jnp.float32)


methods.weighting("kmeans", kind="given", label="k-means", role="baseline")(_score)
