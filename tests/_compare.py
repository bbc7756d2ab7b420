"""Comparisons shared by the tests that train one model two ways (vmapped or looped, sharded or not)."""

import jax
import numpy as np

UPDATE_RTOL = 1e-2  # see `update_mismatch`


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
