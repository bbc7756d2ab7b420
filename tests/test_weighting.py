"""Weighting functions against hand-computed values, the grid's one calling convention, and their properties."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from ape_jax import weighting
from ape_jax.weighting import Weighting


def test_step_upweights_the_largest_ape_with_ties_broken_by_index():
    ape = jnp.array([0.5, 2.0, 0.1, 2.0, 3.0, 0.0, 1.0, 0.2, 0.3, 0.4])
    # thr 0.3 of 10 -> the 3 largest: 3.0 (index 4), then the tie 2.0 at indices 1 and 3
    np.testing.assert_array_equal(weighting.step(ape, 0.3, 5.0), [1, 5, 1, 5, 5, 1, 1, 1, 1, 1])
    # thr 0.2 -> 2 samples: 3.0 and the first of the tied 2.0s
    np.testing.assert_array_equal(weighting.step(ape, 0.2, 3.0), [1, 3, 1, 1, 3, 1, 1, 1, 1, 1])
    # floor: 0.15 of 10 is 1.5 -> 1 sample
    np.testing.assert_array_equal(weighting.step(ape, 0.15, 10.0), [1, 1, 1, 1, 10, 1, 1, 1, 1, 1])


def test_step_counts_exactly_floor_thr_n_despite_float32_thresholds():
    # 0.7 is stored as 0.69999999 in float32; a naive floor would give 6
    assert int((weighting.step(jnp.arange(10.0), 0.7, 2.0) == 2.0).sum()) == 7
    assert int((weighting.step(jnp.arange(10.0), jnp.float32(0.7), 2.0) == 2.0).sum()) == 7


@settings(max_examples=40, deadline=None)
@given(n=st.sampled_from([2, 3, 10, 64, 300]), data=st.data())  # few sizes: each new one compiles the sort
def test_step_weights_are_one_or_w_with_exactly_floor_thr_n_upweighted(n, data):
    k = data.draw(st.integers(1, n - 1))
    floats = st.floats(0, 10, width=32, allow_subnormal=False)  # XLA on CPU flushes subnormals to 0
    ape = np.asarray(data.draw(st.lists(floats, min_size=n, max_size=n)), np.float32)
    w = weighting.step(jnp.asarray(ape), k / n, 5.0)
    assert set(np.unique(np.asarray(w))) <= {1.0, 5.0}
    assert int((w == 5.0).sum()) == k
    assert np.asarray(ape)[np.asarray(w) == 5.0].min() >= np.asarray(ape)[np.asarray(w) == 1.0].max()


def test_softmax_matches_hand_computed_values_and_averages_one():
    ape = jnp.array([0.0, 1.0, 2.0])
    e = np.exp([0.0, 2.0, 4.0])  # tau 0.5
    np.testing.assert_allclose(weighting.softmax(ape, 0.5), 3 * e / e.sum(), rtol=1e-6)
    np.testing.assert_allclose(weighting.softmax(ape, 1e6), [1.0, 1.0, 1.0], rtol=1e-5)  # hot: uniform
    big = weighting.softmax(jnp.array([0.0, 1000.0, 3.0]), 0.1)  # cold: stays finite
    assert np.all(np.isfinite(big)) and float(big.mean()) == pytest.approx(1.0)


def test_uniform_is_ones():
    np.testing.assert_array_equal(weighting.uniform(jnp.array([3.0, 0.0])), [1.0, 1.0])


def test_one_vmapped_program_covers_uniform_step_and_softmax_configs():
    ape = jnp.array([0.1, 5.0, 0.2, 0.3, 4.0, 0.0, 0.5, 0.6, 0.7, 0.8])
    idx = jnp.array([1, 2, 4, 5])
    grid = weighting.stack([Weighting.make("uniform"), Weighting.make("step", thr=0.2, w=5.0),
                            Weighting.make("softmax", tau=0.5)])

    def weights(hp):
        return weighting.batch_weights(ape, weighting.dataset_weights(ape, hp), idx, hp)

    out = jax.jit(jax.vmap(weights))(grid)
    np.testing.assert_array_equal(out[0], [1, 1, 1, 1])
    np.testing.assert_array_equal(out[1], [5, 1, 5, 1])  # the two largest APEs, rows 1 and 4
    np.testing.assert_allclose(out[2], weighting.softmax(ape[idx], 0.5), rtol=1e-6)


def test_score_rows_feed_step_and_given_weightings_in_the_same_program():
    ape = jnp.array([0.1, 5.0, 0.2, 0.3, 4.0, 0.0, 0.5, 0.6, 0.7, 0.8])
    other = jnp.arange(10.0)[::-1]          # a second score: largest at row 0
    given = jnp.linspace(0.5, 1.5, 10)      # weights used as they are
    scores = jnp.stack([ape, other, given])
    idx = jnp.array([0, 1, 4, 9])
    grid = weighting.stack([Weighting.make("step", thr=0.2, w=5.0, source=0),
                            Weighting.make("step", thr=0.2, w=3.0, source=1),
                            Weighting.make("given", source=2),
                            Weighting.make("softmax", tau=0.5, source=1)])

    def weights(hp):
        return weighting.batch_weights(scores, weighting.dataset_weights(scores, hp), idx, hp)

    out = jax.jit(jax.vmap(weights))(grid)
    np.testing.assert_array_equal(out[0], [1, 5, 5, 1])   # APE's top two: rows 1 and 4
    np.testing.assert_array_equal(out[1], [3, 3, 1, 1])   # the other score's top two: rows 0 and 1
    np.testing.assert_allclose(out[2], given[idx])
    np.testing.assert_allclose(out[3], weighting.softmax(other[idx], 0.5), rtol=1e-6)


@pytest.mark.parametrize("kind, kw, message", [
    ("step", {"thr": 0.0}, "THR must be in \\(0, 1\\)"),
    ("step", {"thr": 1.0}, "THR must be in \\(0, 1\\)"),
    ("step", {"thr": 0.1, "w": 0.5}, "W must be >= 1"),
    ("softmax", {"tau": 0.0}, "tau must be > 0"),
    ("softmax", {"tau": -1.0}, "tau must be > 0"),
    ("step", {"thr": float("nan")}, "THR must be in \\(0, 1\\), got nan"),
    ("step", {"thr": 0.1, "w": float("inf")}, "W must be >= 1 and finite, got inf"),
    ("step", {"thr": 0.1, "w": float("nan")}, "W must be >= 1 and finite, got nan"),
    ("softmax", {"tau": float("inf")}, "tau must be > 0 and finite, got inf"),
    ("softmax", {"tau": float("nan")}, "tau must be > 0 and finite, got nan"),
    ("focal", {}, "unknown weighting 'focal'"),
])
def test_invalid_hyperparameters_are_refused(kind, kw, message):
    with pytest.raises(ValueError, match=message):
        Weighting.make(kind, **kw)


# -- properties of the grid's calling convention (one compiled program per test: N and B fixed) --

N, B = 64, 16
_dataset_weights = jax.jit(weighting.dataset_weights)
_batch_weights = jax.jit(lambda scores, idx, hp: weighting.batch_weights(
    scores, weighting.dataset_weights(scores, hp), idx, hp))


def _scores(low=0.0, high=1e4, unique=False):
    """A score table `[2, N] float32` (row 0 APE-like, row 1 another score); no subnormals (XLA flushes them)."""
    return hnp.arrays(np.float32, (2, N), unique=unique,
                      elements=st.floats(low, high, width=32, allow_subnormal=False))


@st.composite
def _configs(draw, kinds=("uniform", "step", "softmax", "given")):
    return Weighting.make(draw(st.sampled_from(kinds)), thr=draw(st.floats(0.01, 0.99)), w=draw(st.floats(1.0, 100.0)),
                          tau=draw(st.floats(0.05, 10.0)), source=draw(st.integers(0, 1)))


_indices = hnp.arrays(np.int32, B, elements=st.integers(0, N - 1))


@settings(max_examples=40, deadline=None)
@given(scores=_scores(-1e4, 1e4), hp=_configs(), idx=_indices)
def test_weights_of_every_kind_are_finite_for_finite_scores(scores, hp, idx):
    assert np.all(np.isfinite(np.asarray(_dataset_weights(scores, hp))))
    assert np.all(np.isfinite(np.asarray(_batch_weights(scores, idx, hp))))


@settings(max_examples=30, deadline=None)
@given(scores=_scores(unique=True), hp=_configs(("uniform", "step", "given")), perm=st.permutations(range(N)))
def test_dataset_weights_are_permutation_equivariant(scores, hp, perm):
    # distinct scores: with ties, the step function's tie-break by index is (rightly) not equivariant
    perm = np.asarray(perm)
    np.testing.assert_array_equal(_dataset_weights(scores[:, perm], hp), np.asarray(_dataset_weights(scores, hp))[perm])


@settings(max_examples=30, deadline=None)
@given(scores=_scores(), hp=_configs(), idx=_indices, perm=st.permutations(range(B)))
def test_batch_weights_are_permutation_equivariant(scores, hp, idx, perm):
    perm = np.asarray(perm)
    np.testing.assert_allclose(_batch_weights(scores, idx[perm], hp), np.asarray(_batch_weights(scores, idx, hp))[perm],
                               rtol=1e-5)


@settings(max_examples=40, deadline=None)
@given(scores=_scores(), hp=_configs(("softmax",)), idx=_indices)
def test_softmax_batch_weights_are_positive_and_average_one(scores, hp, idx):
    w = np.asarray(_batch_weights(scores, idx, hp), np.float64)
    assert np.all(w >= 0) and w.mean() == pytest.approx(1.0, rel=1e-5)


@settings(max_examples=40, deadline=None)
@given(scores=_scores(), thr=st.floats(0.01, 0.99), w=st.floats(1.5, 100.0, width=32), source=st.integers(0, 1))
def test_step_weights_in_the_grid_are_one_or_w_with_floor_thr_n_upweighted(scores, thr, w, source):
    assume(abs(thr * N - round(thr * N)) > 1e-3)  # float32 THR could round ⌊thr·N⌋ either way at an integer
    out = np.asarray(_dataset_weights(scores, Weighting.make("step", thr=thr, w=w, source=source)))
    up = out == np.float32(w)
    assert np.all(up | (out == 1.0))
    assert up.sum() == int(np.floor(thr * N))
    row = scores[source]
    if up.any():  # thr < 1/N upweights nothing
        assert row[up].min() >= row[~up].max()
