"""A configuration's numbers do not depend on what trains beside it (`Budget.width`, `grid.in_blocks`).

XLA rounds a vmapped batch of another size differently, so before fixed widths the same Hopper seed ended up
to 277 apart in return between a 12- and a 20-run program. Here one configuration trains and is evaluated in
a 2-run and in a 7-run program of an MJX task, and its parameters, returns and losses must be bit-identical;
with `budget.width=0` (the whole program at once, the files before fixed widths) they are not.
"""

import jax
import numpy as np
import pytest

from ape_jax.grid import in_blocks
from ape_jax.pipeline import sweep as S

# big enough that XLA rounds a 2- and a 7-wide program differently (at batch 32 and 60 iterations it does not)
SETS = ("protocol.episodes=3", "protocol.horizon=40", "protocol.eval_steps=40", "budget.iterations=300",
        "budget.chunk=150", "budget.seeds=1", "budget.eval_episodes=2", "budget.probe_steps=0",
        "recipe.batch_size=64", "budget.ape_steps=20")
NARROW = ("recipe.step_grid=0.1:5",)                                             # BC-OH + 1 step setting
WIDE = ("recipe.step_grid=0.1:3,0.1:5,0.1:10,0.2:3,0.2:5,0.2:10",)               # BC-OH + 6


def _bc_oh(data_dir, *sets, evaluate=True, seed=None, task=("hopper", "pos", SETS)):
    """BC-OH's parameters, returns and validation losses in a sweep of BC-OH and the step grid `sets` (without
    `evaluate`: its parameters alone); of its run of `seed` (default: its first); on Hopper's states unless `task`
    (env, obs, settings) says otherwise."""
    env, obs, base = task
    spec = S.SweepSpec.make(env, obs, ("bc-oh", "ours-step"), protocol="brax", recipe="mlp",
                            sets=(*base, *sets), data_dir=data_dir)
    prepared = S.prepare(spec)
    programs = S.plan(spec, prepared)
    ape = S.fit_ape(prepared, spec.settings)
    data = prepared.data(prepared.train, ape.train)
    trained = S.train(programs, spec, prepared, data)
    runs = [r for r in trained[0].program.runs if r.method == "bc-oh" and seed in (None, r.seed)]
    j = trained[0].program.runs.index(runs[0])
    if not evaluate:
        return jax.tree.map(lambda x: np.asarray(x[j]), trained[0].params)
    evaluated = S.evaluate(trained, ape, spec.budget.eval_episodes, width=spec.budget.width)
    (done,), (group,), (out,), (losses,) = trained, evaluated.groups, evaluated.outputs, evaluated.losses
    assert group.runs[j].method == "bc-oh"
    return (len(done.program.runs), jax.tree.map(lambda x: np.asarray(x[j]), done.params),
            np.asarray(out["return"][j]), float(losses["val"]["unweighted"][j]))


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("data")


# The two MJX sweeps below take ~90 s of the default run's ~10 minutes on 2 cores: `pytest -m slow` runs them;
# `test_in_blocks_calls_one_shape_and_drops_the_padding` keeps the mechanism in the default run.
@pytest.mark.slow
def test_a_configuration_is_bit_identical_in_a_2_run_and_a_7_run_program_of_an_mjx_task(data_dir):
    n2, params2, returns2, loss2 = _bc_oh(data_dir, *NARROW)
    n7, params7, returns7, loss7 = _bc_oh(data_dir, *WIDE)
    assert (n2, n7) == (2, 7)
    for x, y in zip(jax.tree.leaves(params2), jax.tree.leaves(params7)):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(returns2, returns7)
    assert loss2 == loss7 and np.all(np.isfinite(returns2))


@pytest.mark.slow
def test_without_a_fixed_width_the_same_configuration_differs(data_dir):
    """The control: the whole program at once (`budget.width=0`), the same two sweeps round differently."""
    whole2 = _bc_oh(data_dir, *NARROW, "budget.width=0", evaluate=False)
    whole7 = _bc_oh(data_dir, *WIDE, "budget.width=0", evaluate=False)
    if all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(whole2), jax.tree.leaves(whole7))):
        pytest.skip("this machine's XLA rounds both widths alike here (the 2-core AMD EPYC does not): the "
                    "bit-identity above shows nothing on it")


# ToyCar (no MJX compile) is enough for `first_seed`'s bookkeeping; the widths' own bit-identity is Hopper's, above
TOYCAR = ("toycar", "full", ("budget.iterations=200", "budget.chunk=100", "budget.eval_episodes=2",
                             "budget.probe_steps=0", "budget.ape_steps=20", "recipe.batch_size=64"))


@pytest.mark.integration
def test_a_seed_run_from_first_seed_is_bit_identical_to_the_same_seed_of_a_longer_sweep(data_dir):
    """`budget.first_seed`: a long sweep split by seeds into files computes what one sweep of them all does."""
    n2, params2, returns2, loss2 = _bc_oh(data_dir, *NARROW, "budget.seeds=2", seed=1, task=TOYCAR)
    n1, params1, returns1, loss1 = _bc_oh(data_dir, *NARROW, "budget.seeds=1", "budget.first_seed=1", seed=1,
                                          task=TOYCAR)
    assert (n2, n1) == (4, 2)
    for x, y in zip(jax.tree.leaves(params2), jax.tree.leaves(params1)):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(returns2, returns1)
    assert loss2 == loss1


def test_in_blocks_calls_one_shape_and_drops_the_padding():
    shapes = []

    def mapped(x, scale):
        shapes.append(x.shape)
        return {"y": x * scale}

    out = in_blocks(mapped, 3)(np.arange(7.0), 2.0)
    np.testing.assert_array_equal(out["y"], 2.0 * np.arange(7.0))
    assert shapes == [(3,)] * 3                        # 7 rows: 3 + 3 + 1 padded to 3
    shapes.clear()
    np.testing.assert_array_equal(in_blocks(mapped, None)(np.arange(7.0), 1.0)["y"], np.arange(7.0))
    assert shapes == [(7,)]
    with pytest.raises(ValueError, match="width must be >= 1"):
        in_blocks(mapped, 0)
