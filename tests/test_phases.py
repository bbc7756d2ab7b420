"""The sweep's phases called directly (prepare → plan → fit APE → train → evaluate → assemble), seeds by
identity, and the task records the phases read. ToyCar's `full` observations: no MJX compile."""

import dataclasses

import jax
import numpy as np
import pytest

from ape_jax import methods, tasks
from ape_jax.pipeline import provenance
from ape_jax.pipeline import sweep as S
from ape_jax.pipeline.presets import resolve

SETS = ("budget.iterations=40", "budget.eval_episodes=2", "budget.chunk=20", "budget.seeds=2", "budget.probe_steps=200",
        "recipe.step_grid=0.1:5,0.2:3", "recipe.softmax_grid=1")


def _train(spec):
    prepared = S.prepare(spec)
    programs = S.plan(spec, prepared)
    ape = S.fit_ape(prepared, spec.settings)
    data = prepared.data(prepared.train, ape.train, S.score_table(ape.train, S.method_scores(spec.methods,
                                                                                             prepared.train)))
    return prepared, programs, ape, S.train(programs, spec, prepared, data)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    data_dir = tmp_path_factory.mktemp("data")
    spec = S.SweepSpec.make("toycar", "full", ("bc-so", "bc-oh", "ours-step"), recipe="mlp", sets=SETS,
                            data_dir=data_dir)
    return (spec, *_train(spec))


def test_a_spec_fills_in_what_the_protocol_leaves_to_the_task():
    spec = S.SweepSpec.make("toycar", "full", ("bc-oh",))
    assert spec.protocol.episodes is None and spec.episodes == tasks.get("toycar").episodes == 10
    assert S.SweepSpec.make("hopper", "pos", ("bc-oh",)).episodes == 25   # fca's 50,000 steps, 2,000 per episode
    assert resolve("toycar", "image", preset="default").budget.seeds == 5
    assert resolve("hopper", "image", preset="default").budget.seeds == 3
    with pytest.raises(methods.MethodError, match="unknown method 'nope'"):
        S.SweepSpec.make("hopper", "pos", ("nope",))


@pytest.mark.integration
def test_prepare_splits_by_episode_and_standardises_with_training_statistics(small):
    spec, prepared, *_ = small
    train, val = prepared.train.demos, prepared.val.demos
    assert prepared.train.rows is None and prepared.val.rows is None   # the brax protocol: split by episode
    assert not set(np.asarray(train.episode)) & set(np.asarray(val.episode))
    assert len(set(np.asarray(train.episode))) == 8 and len(set(np.asarray(val.episode))) == 2  # 10 episodes
    obs = np.asarray(prepared.normalizer(train.obs))
    varying = np.asarray(train.obs).std(0) > 1e-3
    np.testing.assert_allclose(obs.mean(0), 0.0, atol=1e-4)
    np.testing.assert_allclose(obs.std(0)[varying], 1.0, rtol=1e-3)
    assert prepared.task.loss == "l1" and prepared.card is None   # the sandbox: L1, a rule-based expert


@pytest.mark.integration
def test_plan_groups_runs_into_their_programs_with_their_history(small):
    spec, prepared, programs, *_ = small
    assert [(p.name, p.cfg.history, len(p.runs)) for p in programs] == [("bc-so", 1, 2), ("grid", 2, 2 + 2 * 2)]
    grid = programs[1]
    assert [(r.method, r.hparams) for r in grid.runs[::2]] == [("bc-oh", {}), ("ours-step", {"thr": 0.1, "w": 5.0}),
                                                               ("ours-step", {"thr": 0.2, "w": 3.0})]
    assert [r.seed for r in grid.runs] == [0, 1] * 3


@pytest.mark.integration
def test_fit_ape_gives_the_raw_ape_by_default_and_divides_by_its_mean_on_request(small):
    import jax.numpy as jnp

    from ape_jax import ape as ape_lib

    spec, prepared, _, ape, _ = small
    raw = ape_lib.errors(ape.params, jnp.asarray(prepared.train.action), jnp.asarray(prepared.train.demos.t))
    assert spec.settings.ape_normalization == "none" and ape.scale == 1.0
    np.testing.assert_array_equal(ape.train, np.asarray(raw))   # no rescaling: the paper's τ means what it meant
    assert np.isclose(ape.raw_mean, float(np.mean(raw)), rtol=1e-6)
    mean = S.fit_ape(prepared, resolve("toycar", "full", recipe="mlp",
                                       sets=[*SETS, "ours-softmax.ape_normalization=mean"]))
    assert np.isclose(np.mean(mean.train), 1.0, rtol=1e-4) and np.isclose(mean.scale, float(np.mean(raw)), rtol=1e-5)
    assert np.isclose(mean.raw_mean, ape.raw_mean, rtol=1e-5)


@pytest.mark.integration
def test_the_softmax_weights_a_batch_by_b_softmax_of_the_raw_ape_over_tau(small):
    import jax.numpy as jnp

    from ape_jax import weighting

    spec, prepared, _, ape, _ = small
    data = prepared.data(prepared.train, ape.train)
    idx = jnp.arange(0, 128 * 7, 7)
    for tau in (0.1, 1.0):
        hp = methods.get("ours-softmax").hparams({"tau": tau}, 2e-4, 0)
        static = weighting.dataset_weights(data.score_table(), hp.weighting)
        w = weighting.batch_weights(data.score_table(), static, idx, hp.weighting)
        z = np.asarray(ape.train, np.float64)[np.asarray(idx)] / tau
        want = 128 * np.exp(z - z.max()) / np.exp(z - z.max()).sum()
        np.testing.assert_allclose(np.asarray(w), want, rtol=1e-4, atol=1e-6)


@pytest.mark.integration
def test_evaluate_and_assemble_give_one_record_per_run_in_plan_order(small):
    spec, prepared, programs, ape, trained = small
    evaluated = S.evaluate(trained, ape, spec.budget.eval_episodes, probe_steps=spec.budget.probe_steps)
    assert [g.name for g in evaluated.groups] == ["h1", "h2"]
    res = S.assemble(spec, prepared, ape, trained, evaluated, timing={})
    assert [(r["method"], r["seed"]) for r in res.runs] == [(r.method, r.seed) for p in programs for r in p.runs]
    for r in res.runs:   # the sandbox is judged by success: "normalized" is its rate in %
        assert r["eval"]["normalized"] == pytest.approx(100 * r["eval"]["success"])
    row = res.summary[0]
    seeds = [r["eval"]["success"] for r in res.runs if r["method"] == row["method"]]
    assert row["metrics"]["success"]["mean"] == pytest.approx(np.mean(seeds))
    assert res.main_metric == "success" and res.methods["bc-so"]["label"] == "BC-SO"
    assert res.protocol["history"] == 2 and res.command is None
    # it trained 40 iterations where its preset gives more (`--set`): the file says so itself
    assert res.config["iterations"] == 40 != res.config["preset_iterations"] == spec.settings.preset_iterations
    # every policy carries the copycat diagnostics, with what they mean beside them
    diag = res.config["diagnostics"]
    assert diag["thresholds"] == {"embedding_ratio": 0.5, "predictability_ratio": 0.5, "control_ratio": 0.25}
    assert diag["velocity"] is None
    assert diag["probe_steps"] == 200
    assert 0 < diag["probe_rows"]["val"] <= diag["probe_rows"]["train"] <= len(prepared.train)
    reference = {r["diagnostics"]["prev_from_action"] for r in res.runs}
    assert len(reference) == 1  # the a_t-alone probe does not depend on the policy
    for r in res.runs:
        d = r["diagnostics"]
        assert d["verdict"] in ("copycat", "not copycat") and d["velocity_ratio"] is None  # ToyCar has no qvel
        assert d["prev_from_state"] is None and d["state_ratio"] is None and diag["state"] is None  # nor qpos
        assert d["embedding_ratio"] == pytest.approx(d["prev_from_embedding"] / d["prev_from_action"])
        assert d["predictability_ratio"] == pytest.approx(d["policy_mse"] / d["expert_mse"])
        assert d["predictability_steps"] > 0 and d["policy_mse"] > 0


@pytest.mark.integration
def test_a_grid_with_one_more_method_leaves_the_shared_configurations_bit_identical(small, tmp_path):
    spec, _, _, _, trained = small
    wider = dataclasses.replace(spec, methods=("bc-so", "bc-oh", "ours-step", "ours-softmax", "kmeans"))
    *_, trained_wider = _train(wider)

    def by_run(trained):
        return {r.ident: jax.tree.map(lambda x: np.asarray(x[i]), t.params)
                for t in trained for i, r in enumerate(t.program.runs)}

    a, b = by_run(trained), by_run(trained_wider)
    assert len(b) == len(a) + 2 + 2 and set(a) < set(b)
    for ident, params in a.items():
        for x, y in zip(jax.tree.leaves(params), jax.tree.leaves(b[ident])):
            np.testing.assert_array_equal(x, y, err_msg=str(ident))


@pytest.mark.integration
def test_run_sweep_from_python_needs_only_the_task_and_defaults_the_cache(tmp_path, monkeypatch):
    """The Python API as documented: `SweepSpec.make` with a task and settings, no `data_dir` (the cache dir)."""
    monkeypatch.setenv("APE_JAX_CACHE", str(tmp_path / "cache"))
    spec = S.SweepSpec.make("toycar", "full", ("bc-oh",), sets=["budget.iterations=20", "budget.eval_episodes=1",
                                                                "budget.chunk=20"])
    assert spec.data_dir is None and spec.recipe.name == "mlp" and spec.protocol.name == "brax"
    res, policies = S.run_sweep(spec, S.Hooks(log=lambda message: None))
    assert [r["method"] for r in res.runs] == ["bc-oh"] and res.runs[0]["status"] == "ok"
    assert res.settings["budget"]["iterations"] == 20 and list(policies) == ["h2"]
    assert len(list((tmp_path / "cache").glob("toycar-full-*.npz"))) == 1   # collected into the default cache
    # it says which code made it, as the command line's results do (this checkout's commit)
    assert res.system["commit"] == provenance.system()["commit"] and res.system["machine"]
    assert res.system["jax"] == jax.__version__


@pytest.mark.integration
def test_policies_kept_at_eval_at_are_the_training_state_there_and_leave_training_unchanged(small, tmp_path):
    """`budget.eval_at`: a chunk stops at each point and the policies there are kept, evaluated and recorded; the
    run goes on bit-identically, and with the lr never decayed the policy at 10 iterations is a 10-iteration run's."""
    spec, *_ = small
    flat = ("recipe.lr_decay_at=", "budget.probe_steps=0")

    def sweep(*sets):
        s = S.SweepSpec.make("toycar", "full", ("bc-oh",), recipe="mlp", sets=(*SETS, *flat, *sets),
                             data_dir=spec.data_dir)
        prepared, programs, ape, trained = _train(s)
        return s, prepared, ape, trained

    s, prepared, ape, trained = sweep("budget.eval_at=10,30")
    assert sorted(trained[0].snapshots) == [10, 30]
    _, _, _, plain = sweep()
    _, _, _, short = sweep("budget.iterations=10")
    for x, y in zip(jax.tree.leaves(trained[0].params), jax.tree.leaves(plain[0].params)):
        np.testing.assert_array_equal(x, y)
    for x, y in zip(jax.tree.leaves(trained[0].snapshots[10]), jax.tree.leaves(short[0].params)):
        np.testing.assert_array_equal(x, y)
    evaluated = S.evaluate(trained, ape, s.budget.eval_episodes)
    res = S.assemble(s, prepared, ape, trained, evaluated, timing={})
    for r in res.runs:
        assert [a["iteration"] for a in r["at"]] == [10, 30]
        assert all(a["eval"]["episodes"] == 2 and a["train_loss"] > 0 for a in r["at"])
    from ape_jax.pipeline import results as results_lib
    results_lib.validate(res.to_json())


def test_a_network_without_an_embedding_gets_its_diagnostics_recorded_absent_not_as_zeros():
    """A plugin's network whose `__call__` takes no `return_embedding`: no probe can read it."""
    import types

    import flax.linen as nn

    class NoEmbedding(nn.Module):
        @nn.compact
        def __call__(self, x):
            return nn.Dense(2)(x)

    group = S.PolicyGroup(2, types.SimpleNamespace(model=NoEmbedding), (S.Run("bc-oh", {}, 0),) * 3, None)
    out = S.group_diagnostics(group, None, None, None, steps=100)
    assert [S.diagnostics_record(out, j) for j in range(3)] == [
        {"absent": "the policy's network gives no embedding (it takes no return_embedding)"}] * 3
