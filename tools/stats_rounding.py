"""How far BatchNorm's running statistics of one configuration move between two programs: the numbers behind
`tests/_compare.py`'s `STATS_RTOL`.

    python tools/stats_rounding.py                                             # this machine's threads
    XLA_FLAGS=--xla_cpu_multi_thread_eigen=false taskset -c 0 python tools/stats_rounding.py   # one core

Trains `tests/test_recipe.py`'s six-wide BatchNorm grid as one vmapped program and each configuration alone,
then prints per configuration `stats_mismatch` against its own lone run (rounding), against the next
configuration's (a real difference), and the largest elementwise relative difference (what the old test
compared).
"""

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "tests"))

import jax  # noqa: E402
import numpy as np  # noqa: E402

from _compare import stats_mismatch  # noqa: E402
from ape_jax.learner import make_train, stack_hparams  # noqa: E402
from test_recipe import BN, GRID, _dataset  # noqa: E402


def main() -> None:
    data, learner = _dataset(), make_train(BN)
    keys = jax.random.split(jax.random.PRNGKey(1), 6)
    grid = stack_hparams(GRID + GRID)
    params, _ = jax.jit(jax.vmap(learner.train, (0, 0, None)))(keys, grid, data)
    single = jax.jit(learner.train)
    stats = [jax.tree.map(lambda x: np.asarray(x[i]), params["batch_stats"]) for i in range(6)]
    for i in range(6):
        alone, _ = single(keys[i], jax.tree.map(lambda x: x[i], grid), data)
        pairs = zip(jax.tree.leaves(stats[i]), map(np.asarray, jax.tree.leaves(alone["batch_stats"])))
        elementwise = max(float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-30))) for a, b in pairs)
        print(f"configuration {i}: rounding {stats_mismatch(stats[i], alone['batch_stats']):.2e}, another "
              f"configuration {stats_mismatch(stats[(i + 1) % 6], alone['batch_stats']):.2e}, largest elementwise "
              f"relative difference {elementwise:.2e}")


if __name__ == "__main__":
    main()
