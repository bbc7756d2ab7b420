"""The method registry and the plugin contract: names are unique, lists derive from it, plugins join the grid."""

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import methods
from ape_jax.learner import Hparams
from ape_jax.weighting import SoftmaxKnobs, StepKnobs
from experiments import sweep

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PLUGIN = '''
import jax.numpy as jnp
from ape_jax import methods

@methods.weighting("action-norm")   # kind="step" by default: ranked at the preset's (THR, W) grid, like ours-step
def action_norm(key, actions, t):    # actions [N, A] float32, t [N] int32 -> scores [N] float32
    return jnp.sum(actions ** 2, axis=-1)
'''


def test_every_builtin_is_registered_once_with_its_program_and_role():
    names = methods.names()
    assert names[:5] == ("bc-so", "bc-oh", "bc-full", "ours-step", "ours-softmax")
    assert set(names) == {"bc-so", "bc-oh", "bc-full", "ours-step", "ours-softmax", "bcpd", "actfreq", "kmeans",
                          "boosting", "history-dropout", "fca", "fca-ib", "dagger", "rap", "palr", "mine",
                          "action-chunks", "priming", "channel-dropout", "ptp"}
    assert methods.default() == ("bc-so", "bc-oh", "ours-step", "ours-softmax")   # bc-full: asked for by name
    assert set(methods.shortcuts()["baselines"]) == set(names) - set(methods.default()) - {"bc-full"}
    programs = {n: methods.get(n).program for n in names}
    assert {n for n, p in programs.items() if p == "grid"} == {"bc-oh", "ours-step", "ours-softmax", "bcpd",
                                                               "actfreq", "kmeans", "history-dropout"}
    assert methods.get("bc-so").history == 1 and [n for n in names if methods.get(n).online] == ["dagger"]
    assert {n for n in names if methods.get(n).score is not None} == {"bcpd", "actfreq", "kmeans"}


def test_a_taken_or_unknown_name_is_refused_with_the_registered_names():
    with methods.scratch():
        with pytest.raises(methods.MethodError, match=r"'ours-step' is already registered .*registered: bc-so, bc-oh"):
            methods.weighting("ours-step")(lambda key, a, t: a[:, 0])
    with pytest.raises(methods.MethodError, match=r"unknown method 'nope'; valid: bc-so, bc-oh, bc-full, ours-step"):
        methods.get("nope")
    with pytest.raises(methods.MethodError, match="listed twice"):
        methods.resolve("bc-oh,bc-oh")
    assert methods.resolve("bc-oh, baselines")[0] == "bc-oh" and "dagger" in methods.resolve("all")


def test_scratch_undoes_registrations():
    with methods.scratch():
        methods.weighting("tmp-method", kind="given")(lambda key, a, t: jnp.ones(a.shape[0], jnp.float32))
        assert "tmp-method" in methods.names("plugin")
    assert "tmp-method" not in methods.names()


def test_a_program_shared_with_another_history_or_learner_is_refused():
    with methods.scratch(), pytest.raises(methods.MethodError, match="program 'grid' with another history"):
        methods.register(methods.Method("short", "Short", grid=lambda ctx: [{}],
                                        hparams=lambda s, lr, row: Hparams.make(lr=lr), history=1))


def test_plugin_weightings_become_traced_hparams_of_their_kind_on_their_score_row():
    with methods.scratch():
        for kind in ("step", "softmax", "given"):
            methods.weighting(f"p-{kind}", kind=kind)(lambda key, a, t: jnp.ones(a.shape[0], jnp.float32))
        # a step (softmax) weighting without a fixed grid owns one, as ours-step (ours-softmax) does
        assert methods.get("p-step").knobs is StepKnobs and methods.get("p-softmax").knobs is SoftmaxKnobs
        assert methods.get("p-given").knobs is None and "p-step" in methods.sharing(StepKnobs)
        ctx = methods.GridContext(task=None, n_train=10, knobs={"p-step": StepKnobs(((0.1, 5.0), (0.2, 3.0))),
                                                                "p-softmax": SoftmaxKnobs((0.5,))})
        assert methods.get("p-step").settings(ctx) == [{"thr": 0.1, "w": 5.0}, {"thr": 0.2, "w": 3.0}]
        assert methods.get("p-softmax").settings(ctx) == [{"tau": 0.5}] and methods.get("p-given").settings(ctx) == [{}]
        hp = methods.get("p-step").hparams({"thr": 0.2, "w": 3.0}, 1e-3, 2)
        assert (int(hp.weighting.kind), float(hp.weighting.w), int(hp.weighting.source)) == (1, 3.0, 2)
        assert int(methods.get("p-softmax").hparams({"tau": 0.5}, 1e-3, 1).weighting.kind) == 2
        methods.weighting("p-fixed", grid=[{"thr": 0.3, "w": 2.0}])(lambda key, a, t: a[:, 0])
        assert methods.get("p-fixed").settings(ctx) == [{"thr": 0.3, "w": 2.0}]
        with pytest.raises(methods.MethodError, match="keys"):
            methods.weighting("p-bad", kind="softmax", grid=[{"thr": 0.1}])


@pytest.mark.parametrize("body, problem", [
    ("return actions[:, 0][:, None]", r"returned shape \(6, 1\), expected \(6,\)"),
    ("return jnp.arange(actions.shape[0])", "returned dtype int32, expected float32"),
    ("return jnp.full(actions.shape[0], jnp.nan, jnp.float32)", "returned 6 non-finite scores"),
    ("raise RuntimeError('boom')", "raised RuntimeError: boom"),
])
def test_bad_scores_are_refused_naming_the_method(body, problem):
    ns = {"jnp": jnp}
    exec(f"def bad(key, actions, t):\n    {body}\n", ns)
    with methods.scratch():
        methods.weighting("bad-plugin")(ns["bad"])
        with pytest.raises(methods.PluginError, match=f"method 'bad-plugin': .*{problem}"):
            methods.get("bad-plugin").score(jax.random.PRNGKey(0), jnp.ones((6, 2)), jnp.arange(6))
    with methods.scratch():
        methods.weighting("neg", kind="given")(lambda key, a, t: -jnp.ones(a.shape[0], jnp.float32))
        with pytest.raises(methods.PluginError, match="must be >= 0"):
            methods.get("neg").score(jax.random.PRNGKey(0), jnp.ones((6, 2)), jnp.arange(6))


def test_run_keys_come_from_identity_alone():
    a = methods.run_key(0, "ours-step", {"thr": 0.1, "w": 5.0})
    assert np.array_equal(a, methods.run_key(0, "ours-step", {"w": 5.0, "thr": 0.1}))  # order of keys: no matter
    others = [methods.run_key(1, "ours-step", {"thr": 0.1, "w": 5.0}), methods.run_key(0, "ours-step", {"thr": 0.2,
              "w": 5.0}), methods.run_key(0, "bcpd", {"thr": 0.1, "w": 5.0})]
    assert all(not np.array_equal(a, o) for o in others)


def _plugin_dir(tmp_path, name, text):
    d = tmp_path / "plugins"
    d.mkdir(exist_ok=True)
    (d / f"{name}.py").write_text(textwrap.dedent(text))
    return d


def _run_sweep(args, cwd, plugin_dir):
    env = {**os.environ, "PYTHONPATH": str(plugin_dir)}
    return subprocess.run([sys.executable, "-m", "experiments.sweep", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


def test_the_readme_plugin_runs_from_outside_the_repository_in_the_grid_program(tmp_path):
    """The README's example, as a user would run it: a module in another folder, the sweep started there."""
    plugins = _plugin_dir(tmp_path, "my_weighting", PLUGIN)
    out = tmp_path / "run"
    proc = _run_sweep(["--plugins", "my_weighting", "--methods", "bc-oh,action-norm",
                       "--env", "toycar", "--obs", "full",
                       "--iterations", "20", "--eval-episodes", "1", "--step-grid", "0.1:5,0.2:3", "--quiet",
                       "--set", "budget.probe_steps=0",  # no copycat diagnostics: not this test's subject
                       "--out", str(out), "--data-dir", str(tmp_path / "data")], tmp_path, plugins)
    assert proc.returncode == 0, proc.stderr[-2000:]
    r = json.loads((out / "results.json").read_text())
    assert [(run["method"], run["hparams"]) for run in r["runs"]] == [
        ("bc-oh", {}), ("action-norm", {"thr": 0.1, "w": 5.0}), ("action-norm", {"thr": 0.2, "w": 3.0})]
    assert all(run["status"] == "ok" for run in r["runs"])
    assert r["config"]["score_rows"] == ["ape", "action-norm"]
    assert r["methods"]["action-norm"] == {"label": "action-norm", "role": "plugin", "program": "grid",
                                           "online": False}
    # one compiled program: the grid's curves hold BC-OH and the plugin's runs, and there is no other program
    assert sorted(p.name for p in (out / "curves").iterdir()) == ["grid.csv"]
    grid = (out / "curves" / "grid.csv").read_text()
    assert "action-norm" in grid and "bc-oh" in grid
    assert "action-norm" in (out / "results.csv").read_text() and "action-norm" in proc.stdout


@pytest.mark.parametrize("text, problem", [
    ("import nonexistent_module_xyz\n", "plugin 'broken' failed to import: ModuleNotFoundError"),
    ("x = 1\n", "plugin 'broken' registered no method"),
    ("from ape_jax import methods\nmethods.weighting('bc-oh')(lambda k, a, t: a[:, 0])\n",
     "plugin 'broken': method 'bc-oh' is already registered"),
])
def test_a_plugin_that_cannot_be_used_is_refused_in_one_line(tmp_path, text, problem):
    plugins = _plugin_dir(tmp_path, "broken", text)
    proc = _run_sweep(["--plugins", "broken", "--env", "toycar", "--obs", "full", "--out", str(tmp_path / "run")],
                      tmp_path, plugins)
    assert proc.returncode == 2 and problem in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert not (tmp_path / "run").exists()


def test_a_plugin_with_bad_scores_is_refused_before_training(tmp_path, capsys):
    ns = {}
    with methods.scratch():
        exec("import jax.numpy as jnp\nfrom ape_jax import methods\n"
             "@methods.weighting('wrong-shape')\ndef f(key, a, t):\n    return jnp.ones((3,), jnp.float32)\n", ns)
        with pytest.raises(SystemExit) as exc:
            sweep.main(["--methods", "bc-oh,wrong-shape", "--env", "toycar", "--obs", "full", "--iterations", "20",
                        "--out", str(tmp_path / "run"), "--data-dir", str(tmp_path / "data")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "method 'wrong-shape': its score function returned shape (3,)" in err
    assert not (tmp_path / "run").exists()


def test_the_listing_order_does_not_depend_on_which_module_was_imported_first():
    code = ("import ape_jax.baselines.bcpd\n"  # it registers while the registry loads the others
            "from ape_jax import methods\nprint(','.join(methods.names()))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines()[-1] == ",".join(methods.names())
    assert methods.names("baseline") == ("actfreq", "action-chunks", "bcpd", "boosting", "channel-dropout", "dagger",
                                         "fca", "fca-ib", "history-dropout", "kmeans", "mine", "palr", "priming", "ptp",
                                         "rap")
