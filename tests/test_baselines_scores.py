"""Per-sample scores and weights of the BCPD, ActFreq and k-means baselines on problems with known answers."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ape_jax.baselines import actfreq, bcpd, kmeans


def _segments(rng, levels, lengths, noise=0.05):
    """Piecewise-constant actions `[sum(lengths), A]` plus Gaussian noise."""
    a = np.concatenate([np.tile(np.asarray(lv, np.float32), (n, 1)) for lv, n in zip(levels, lengths)])
    return (a + noise * rng.normal(size=a.shape)).astype(np.float32)


# ---------------------------------------------------------------- BCPD


def test_bcpd_peaks_at_a_planted_change():
    rng = np.random.default_rng(0)
    actions = _segments(rng, [[1.0, 0.0, -1.0], [-1.0, 0.5, 1.0]], [70, 80])
    score = np.asarray(bcpd.changepoint_prob(actions, np.arange(150)))
    assert score.shape == (150,) and score.dtype == np.float32 and np.all(np.isfinite(score))
    assert np.all((score >= 0) & (score <= 1))
    assert abs(int(score.argmax()) - 70) <= 1
    assert score[70] > 0.5 and score[70] > 100 * np.median(score)
    assert score[0] == 0.0  # an episode's first step is never flagged


def test_bcpd_restarts_at_every_episode():
    rng = np.random.default_rng(1)
    ep1 = _segments(rng, [[2.0, 2.0], [0.0, 1.0]], [40, 60])    # change at 40
    ep2 = _segments(rng, [[0.0, 1.0], [-2.0, -1.0]], [50, 70])  # continues ep1's last level; change at 50
    t = np.r_[np.arange(100), np.arange(120)]
    score = np.asarray(bcpd.changepoint_prob(np.r_[ep1, ep2], t))
    assert abs(int(score[:100].argmax()) - 40) <= 1
    assert abs(int(score[100:].argmax()) - 50) <= 1
    assert score[100] == 0.0
    assert score[101:].max() == score[150] and score[150] > 100 * np.median(score[100:])
    # Reversed, episode 1 ends at a level far from episode 2's start, and the
    # standardisation is unchanged: after the reset episode 2 cannot tell.
    reversed_first = np.asarray(bcpd.changepoint_prob(np.r_[ep1[::-1], ep2], t))
    assert reversed_first[100] == 0.0  # a boundary is not a change, however far the levels jump
    np.testing.assert_allclose(reversed_first[100:], score[100:], rtol=1e-4, atol=1e-6)


def _reference_bcpd(actions, t, hazard, prior_var, noise_var, max_run):
    """The recursion of `bcpd`'s docstring in float64 loops, each predictive from its explicit window."""
    x = np.asarray(actions, np.float64)
    std = x.std(axis=0)
    x = (x - x.mean(axis=0)) / np.where(std > 1e-6, std, 1.0)

    def density(value, mean, var):
        return np.prod(np.exp(-0.5 * (value - mean) ** 2 / var) / np.sqrt(2 * np.pi * var))

    score, p = np.zeros(len(x)), None
    for i in range(len(x)):
        if t[i] == 0:
            p = np.eye(max_run)[0]
            continue
        q = np.zeros(max_run)
        q[0] = hazard * density(x[i], 0.0, prior_var + noise_var)
        for j in np.flatnonzero(p):
            s = j + 1                              # the segment's length before x_i (its last s actions)
            precision = 1 / prior_var + s / noise_var
            mean = x[i - s:i].sum(axis=0) / noise_var / precision
            q[min(j + 1, max_run - 1)] += (1 - hazard) * p[j] * density(x[i], mean, 1 / precision + noise_var)
        p = q / q.sum()
        score[i] = p[0]
    return score


def test_bcpd_matches_a_loop_reference_with_truncation_and_resets():
    rng = np.random.default_rng(3)
    actions = np.cumsum(rng.normal(size=(40, 2)), axis=0).astype(np.float32)  # a random walk: scores of all sizes
    t = np.r_[np.arange(25), np.arange(15)]
    kw = dict(hazard=0.05, prior_var=2.0, noise_var=0.3, max_run=8)  # segments outgrow max_run
    expected = _reference_bcpd(actions, t, **kw)
    assert 0.01 < np.median(expected) < 0.9
    np.testing.assert_allclose(bcpd.changepoint_prob(actions, t, **kw), expected, rtol=1e-3, atol=1e-6)


def test_bcpd_truncation_only_matters_beyond_max_run():
    rng = np.random.default_rng(2)
    actions = _segments(rng, [[0.0, 1.0, 0.0], [1.0, 0.0, 1.0], [0.0, 0.0, -1.0]], [30, 30, 40])
    t = np.arange(100)
    long = np.asarray(bcpd.changepoint_prob(actions, t, max_run=100))
    # Runs never exceed the episode's 100 steps, so more bins change nothing.
    np.testing.assert_allclose(bcpd.changepoint_prob(actions, t, max_run=160), long, rtol=1e-5, atol=1e-7)
    short = np.asarray(bcpd.changepoint_prob(actions, t, max_run=8))  # heavily truncated: still finds both changes
    assert set(np.argsort(short)[-2:]) == {30, 60}


@settings(max_examples=15, deadline=None)
@given(lengths=st.lists(st.integers(1, 20), min_size=1, max_size=6), seed=st.integers(0, 2**16),
       hazard=st.floats(1e-3, 0.5))
def test_bcpd_is_a_probability_zero_at_episode_starts_and_blind_to_units(lengths, seed, hazard):
    n = 48  # one shape, one compile: the last episode takes the remaining steps
    t = np.concatenate([np.arange(m) for m in lengths] + [np.arange(n)])[:n]
    rng = np.random.default_rng(seed)
    actions = rng.normal(size=(n, 3)).astype(np.float32)
    score = np.asarray(bcpd.changepoint_prob(actions, t, hazard=hazard, max_run=16))
    assert np.all(np.isfinite(score)) and np.all((score >= 0) & (score <= 1))
    assert np.all(score[t == 0] == 0) and np.all(score[t > 0] > 0)
    # Standardisation per dimension: new units and offsets give the same scores.
    rescaled = actions * np.float32([100.0, 0.01, 3.0]) + np.float32([5.0, -2.0, 0.0])
    np.testing.assert_allclose(bcpd.changepoint_prob(rescaled, t, hazard=hazard, max_run=16), score,
                               rtol=2e-3, atol=1e-5)


def test_bcpd_new_hyperparameters_do_not_recompile():
    actions, t = np.zeros((12, 2), np.float32), np.arange(12)
    bcpd.changepoint_prob(actions, t, max_run=4)
    compiled = bcpd._scores._cache_size()
    bcpd.changepoint_prob(actions + 1, t, hazard=0.3, prior_var=2.0, noise_var=0.5, max_run=4)
    assert bcpd._scores._cache_size() == compiled


def test_bcpd_refuses_bad_arguments():
    actions, t = np.zeros((10, 2), np.float32), np.arange(10)
    with pytest.raises(ValueError, match="actions must be"):
        bcpd.changepoint_prob(actions[:, 0], t)
    with pytest.raises(ValueError, match="t must be"):
        bcpd.changepoint_prob(actions, t[:9])
    with pytest.raises(ValueError, match="hazard"):
        bcpd.changepoint_prob(actions, t, hazard=1.0)
    with pytest.raises(ValueError, match="noise_var"):
        bcpd.changepoint_prob(actions, t, noise_var=0.0)
    with pytest.raises(ValueError, match="max_run"):
        bcpd.changepoint_prob(actions, t, max_run=1)


# ---------------------------------------------------------------- ActFreq


def test_actfreq_hand_example():
    # bins=2 over [0, 1]: edges 0, 0.5, 1 -> counts 3 and 1 -> weights ∝ 1/3, 1/3, 1/3, 1, mean 1
    actions = np.array([[0.0], [0.1], [0.2], [1.0]], np.float32)
    w = actfreq.weights(actions, bins=2)
    assert w.dtype == np.float32 and w.shape == (4,)
    np.testing.assert_allclose(w, [2 / 3, 2 / 3, 2 / 3, 2.0], rtol=1e-6)


def test_actfreq_bin_edges_are_equal_width_with_the_maximum_in_the_last_bin():
    actions = np.array([[0.0, 5.0], [0.25, 5.0], [0.5, 5.0], [0.75, 5.0], [1.0, 5.0]], np.float32)
    # an edge belongs to the bin above it; a constant dimension is a single bin
    np.testing.assert_array_equal(actfreq.bin_index(actions, bins=2), [[0, 0], [0, 0], [1, 0], [1, 0], [1, 0]])
    np.testing.assert_array_equal(actfreq.bin_index(actions, bins=4)[:, 0], [0, 1, 2, 3, 3])
    np.testing.assert_array_equal(actfreq.weights(np.ones((7, 3), np.float32)), np.ones(7))


def test_actfreq_ranks_rare_joint_bins_highest():
    # Each dimension alone is balanced (4 low, 4 high); the joint bins are 3, 3, 1, 1.
    actions = np.array([[0, 0]] * 3 + [[1, 1]] * 3 + [[0, 1], [1, 0]], np.float32)
    w = actfreq.weights(actions, bins=2)
    np.testing.assert_allclose(w, [8 / 12] * 6 + [2.0, 2.0], rtol=1e-6)  # N / (K n_b) with K = 4


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 60), a=st.integers(1, 3), bins=st.integers(1, 6), seed=st.integers(0, 2**16))
def test_actfreq_weights_average_one_and_each_bin_carries_n_over_k(n, a, bins, seed):
    actions = np.random.default_rng(seed).uniform(-1, 1, size=(n, a)).astype(np.float32)
    idx = actfreq.bin_index(actions, bins)
    assert idx.min() >= 0 and idx.max() < bins
    w = actfreq.weights(actions, bins)
    assert w.mean() == pytest.approx(1.0, rel=1e-6)
    keys = [tuple(row) for row in idx]
    totals = {key: w[[k == key for k in keys]].sum() for key in set(keys)}
    np.testing.assert_allclose(list(totals.values()), n / len(totals), rtol=1e-5)


def test_actfreq_refuses_bad_arguments():
    with pytest.raises(ValueError, match="actions must be"):
        actfreq.weights(np.zeros(5, np.float32))
    with pytest.raises(ValueError, match="bins"):
        actfreq.weights(np.zeros((5, 2), np.float32), bins=0)
    with pytest.raises(ValueError, match="finite"):
        actfreq.weights(np.array([[0.0], [np.nan]], np.float32))


# ---------------------------------------------------------------- k-means


def _blobs(seed, sizes):
    """Six tight blobs centred at ±10 on each axis of 3-D space (at least 14 apart), and their labels."""
    rng = np.random.default_rng(seed)
    means = 10.0 * np.r_[np.eye(3), -np.eye(3)]
    truth = np.repeat(np.arange(len(sizes)), sizes)
    return (means[truth] + 0.1 * rng.normal(size=(len(truth), 3))).astype(np.float32), truth


def test_kmeans_recovers_planted_clusters_and_weights_them_by_inverse_size():
    sizes = [40, 25, 15, 10, 6, 4]
    x, truth = _blobs(0, sizes)
    fit = jax.vmap(functools.partial(kmeans.fit, k=6, iterations=20), in_axes=(0, None))
    _, labels = fit(jax.random.split(jax.random.PRNGKey(0), 5), x)
    for run in np.asarray(labels):
        table = np.zeros((6, 6), int)
        np.add.at(table, (truth, run), 1)
        # the same partition up to a permutation: one non-empty cell per row and per column
        assert np.all((table > 0).sum(axis=0) == 1) and np.all((table > 0).sum(axis=1) == 1)
    w = np.asarray(kmeans.weights(jax.random.PRNGKey(3), x, k=6, iterations=20))
    np.testing.assert_allclose(w, 100 / (6 * np.asarray(sizes, np.float64)[truth]), rtol=1e-5)


def test_kmeans_weight_formula_on_a_hand_example():
    labels = jnp.array([0] * 6 + [2] * 3 + [1])  # sizes 6, 1, 3 (and cluster 3 empty)
    raw = np.r_[[10 / 6] * 6, [10 / 3] * 3, [10.0]]  # Σ_j n_j / n_c(i)
    expected = raw / raw.mean()                      # 10/18, 10/9, 10/3
    np.testing.assert_allclose(kmeans.cluster_weights(labels, 4), expected, rtol=1e-6)
    np.testing.assert_allclose(kmeans.cluster_weights(labels, 3), expected, rtol=1e-6)
    np.testing.assert_allclose(expected[[0, 6, 9]], [10 / 18, 10 / 9, 10 / 3], rtol=1e-12)


def test_kmeans_plus_plus_never_picks_a_chosen_point_twice():
    x = jnp.asarray(np.random.default_rng(4).normal(size=(6, 2)), jnp.float32)
    for seed in range(4):
        centers, labels = kmeans.fit(jax.random.PRNGKey(seed), x, k=6, iterations=0)
        # squared-distance sampling gives chosen points probability 0: the centers are the 6 points
        np.testing.assert_array_equal(np.sort(np.asarray(labels)), np.arange(6))
        np.testing.assert_array_equal(centers[labels], x)


def test_kmeans_lloyd_reaches_a_fixed_point_and_is_deterministic():
    x = jnp.asarray(np.random.default_rng(5).normal(size=(200, 2)), jnp.float32)
    key = jax.random.PRNGKey(7)
    centers, labels = kmeans.fit(key, x, k=5, iterations=50)
    again_centers, again_labels = kmeans.fit(key, x, k=5, iterations=50)
    np.testing.assert_array_equal(again_centers, centers)
    np.testing.assert_array_equal(again_labels, labels)
    for j in range(5):
        np.testing.assert_allclose(centers[j], x[labels == j].mean(axis=0), atol=1e-5)
    np.testing.assert_array_equal(kmeans.weights(key, x, k=5), kmeans.weights(key, x, k=5))


def test_kmeans_with_fewer_distinct_points_than_clusters_leaves_a_cluster_empty():
    points = np.array([[3.0, 3.0], [4.0, 4.0], [8.0, 3.0]], np.float32)
    x = jnp.asarray(points[[0, 0, 0, 0, 1, 1, 2, 2]])
    centers, labels = kmeans.fit(jax.random.PRNGKey(0), x, k=4, iterations=5)
    # every center is a data point: the clusters' means, and the empty cluster's unmoved initial center
    assert all(np.any(np.all(points == c, axis=1)) for c in np.asarray(centers))
    assert len(np.unique(np.asarray(labels))) == 3  # a duplicate center loses every tie: its cluster stays empty
    w = kmeans.weights(jax.random.PRNGKey(0), x, k=4, iterations=5)
    np.testing.assert_allclose(w, np.r_[[8 / 12] * 4, [8 / 6] * 4], rtol=1e-6)  # N / (K n) with K = 3


def test_kmeans_refuses_bad_arguments():
    with pytest.raises(ValueError, match="k must be"):
        kmeans.fit(jax.random.PRNGKey(0), jnp.zeros((3, 2)), k=4)
    with pytest.raises(ValueError, match="x must be"):
        kmeans.fit(jax.random.PRNGKey(0), jnp.zeros(5), k=2)
    with pytest.raises(ValueError, match="labels must be"):
        kmeans.cluster_weights(jnp.zeros((2, 2), jnp.int32), 2)
