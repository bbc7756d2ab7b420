"""Comparisons shared by the tests that train one model two ways (vmapped or looped, sharded or not)."""

import jax
import numpy as np

UPDATE_RTOL = 1e-2  # see `update_mismatch`
STATS_RTOL = 1e-3  # see `stats_mismatch`


def update_mismatch(params, reference, init) -> float:
    """`‖params − reference‖ / ‖reference − init‖` over all leaves: how far two trainings from `init` disagree.

    Comparing two programs that train the same model (vmapped or not, sharded or
    not) can only be up to float32 rounding: XLA:CPU blocks its GEMMs by shape and
    CPU, so gradients differ in their last bits, and Adam normalises every
    gradient component, so a component whose gradient is within rounding of zero
    may move by up to ±lr in either program. Elementwise tolerances on trained
    parameters are therefore not robust after many steps, and the tests train a
    few. The update as a whole agrees to ~1e-6 of its norm on Intel and jax 0.9.2
    to 0.11; a row trained with another configuration's weighting moves 60-130%
    of it away, with another key ~40x (measured): `UPDATE_RTOL` tells them apart.
    """
    diff = sum(float(np.sum((np.asarray(a, np.float64) - np.asarray(b)) ** 2))
               for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(reference)))
    update = sum(float(np.sum((np.asarray(b, np.float64) - np.asarray(c)) ** 2))
                 for b, c in zip(jax.tree.leaves(reference), jax.tree.leaves(init)))
    assert update > 0, "the reference did not train"
    return (diff / update) ** 0.5


def stats_mismatch(stats, reference) -> float:
    """The largest `max|stats − reference| / max|reference − start|` over BatchNorm's running-statistic leaves.

    A running mean is an exponential average of batch means, each a float32 sum over
    the batch, and the same model trained in two programs rounds those sums in another
    order (XLA:CPU splits a reduction by its shape and by how many threads share it:
    the same test passes pinned to one core and fails on two on an Intel Xeon). A
    sum's rounding error is bounded relative to the sum of its terms' magnitudes, not
    to the sum itself, so an element near zero can differ by 1.5e-4 of itself
    (measured: −0.027384464 against −0.027388610) while the leaf agrees to ~1e-5 of
    its own scale. So each leaf is compared against how far it moved from its start
    (mean 0, variance 1). Measured by `tools/stats_rounding.py` on the six-wide grid of
    `tests/test_recipe.py` (2-core AMD EPYC, one thread and two): rounding moved a leaf by at most 4.3e-5 of that
    (elementwise, up to 4.9e-4 of an element), another configuration's statistics by
    1.5-1.8 times it. `STATS_RTOL` = 1e-3 sits between, 20x above the rounding.
    """
    worst = 0.0
    for name, leaves in (("mean", 0.0), ("var", 1.0)):
        for a, b in zip(_stat_leaves(stats, name), _stat_leaves(reference, name)):
            a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
            moved = np.abs(b - leaves).max()
            assert moved > 0, "the reference's statistics never moved"
            worst = max(worst, float(np.abs(a - b).max() / moved))
    return worst


def _stat_leaves(stats, name):
    """The leaves called `name` (`"mean"` or `"var"`) of a Flax `batch_stats` collection, in a fixed order."""
    flat = jax.tree_util.tree_flatten_with_path(stats)[0]
    return [leaf for path, leaf in flat if getattr(path[-1], "key", None) == name]
