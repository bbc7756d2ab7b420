"""The main job end to end on a shrunken preset (ToyCar: no MJX compile), and its refusals."""

import csv
import json
import pathlib

import numpy as np
import pytest

from ape_jax import methods, tasks
from ape_jax.learner import Hparams
from ape_jax.pipeline.presets import SOFTMAX_GRID, STEP_GRID
from experiments import sweep


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    # the diagnostics' fits shortened (quick's 500 steps): they are tested in test_diagnostics and test_phases
    argv = ["--env", "toycar", "--obs", "full", "--iterations", "30", "--eval-episodes", "2", "--seeds", "2",
            "--set", "budget.probe_steps=100", "--out", str(out / "run"), "--data-dir", str(out / "data")]
    import contextlib
    import io

    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert sweep.main(argv) == 0
    return out / "run", argv, printed.getvalue()


@pytest.mark.integration
def test_sweep_writes_results_matching_the_schema_with_every_configuration_and_seed(finished):
    out, argv, _ = finished
    r = json.loads((out / "results.json").read_text())
    assert r["schema"] == 3 and (r["env"], r["obs"], r["preset"]) == ("toycar", "full", "quick")
    assert r["command"] == ["python", "-m", "experiments.sweep", *argv]
    assert r["protocol"] == {"name": "brax", "frame_skip": None, "standard_frame_skip": None, "episode_length": 300,
                             "reward_scale": 1.0, "collect_transitions": None, "train_transitions": None,
                             "val_transitions": None, "history": 2, "split": "episodes",
                             "eval_steps": None}   # the sandbox takes its own settings only
    # the three records, apart and whole: they resolve back to what ran
    assert set(r["settings"]) == {"protocol", "budget", "recipe"} and r["settings"]["recipe"]["name"] == "mlp"
    assert r["settings"]["budget"]["iterations"] == 30 and r["settings"]["protocol"]["split"] == "episodes"
    from ape_jax.pipeline import results as results_lib
    from ape_jax.pipeline.presets import resolve
    again = results_lib.load(out / "results.json").records()
    assert again == resolve("toycar", "full", sets=["budget.iterations=30", "budget.eval_episodes=2",
                                                      "budget.seeds=2", "budget.probe_steps=100"])
    assert r["config"]["env"]["episode_length"] == 300 and r["config"]["env"]["dt"] == pytest.approx(0.1)
    expected = {("bc-so", ()), ("bc-oh", ())} | {("ours-step", (("thr", t), ("w", w))) for t, w in STEP_GRID} | \
               {("ours-softmax", (("tau", tau),)) for tau in SOFTMAX_GRID}
    seen = {}
    for run in r["runs"]:
        key = (run["method"], tuple(sorted(run["hparams"].items())))
        seen.setdefault(key, set()).add(run["seed"])
        assert run["status"] == "ok" and run["error"] is None
        assert run["eval"]["episodes"] == 2 and set(tasks.get("toycar").metrics) <= set(run["eval"])
        assert run["eval"]["normalized"] == pytest.approx(100 * run["eval"]["success"])
        for split in ("train", "val"):
            assert set(run["losses"][split]) == {"unweighted", "changepoint", "copycat"}
    assert set(seen) == expected and all(s == {0, 1} for s in seen.values())
    assert [run["method"] for run in r["runs"]] == sorted((run["method"] for run in r["runs"]),
                                                         key=methods.names().index)
    assert len(r["summary"]) == len(expected) and all(row["n_seeds"] == 2 for row in r["summary"])
    assert r["config"]["iterations"] == 30 and r["config"]["ape_normalization"] == "none"
    assert r["config"]["data"]["settings"]["episodes"] == 10   # the task's demonstration count
    from ape_jax.pipeline import data as data_lib
    meta = json.loads(data_lib.meta_path(pathlib.Path(r["config"]["data"]["path"])).read_text())
    assert r["config"]["data"]["sha256"] == meta["sha256"]   # which collection of those settings it trained on
    quantiles = r["config"]["ape"]["quantiles"]
    assert len(quantiles) == 101 and quantiles == sorted(quantiles)
    t = r["timing"]
    assert t["compile_s"] + t["train_s"] + t["eval_s"] <= t["total_s"] and r["system"]["backend"] == "cpu"
    assert (out / "results.csv").read_text().count("\n") == len(expected) + 1
    assert (out / "params" / "h2").is_dir() and (out / "params" / "h1").is_dir()


@pytest.mark.integration
def test_each_record_carries_its_own_runs_curve(finished):
    """results.json's curve of each run is the per-iteration curve OUT/curves/ logged for that run, not another's."""
    out, _, _ = finished
    r = json.loads((out / "results.json").read_text())
    logged = {}
    for name in ("grid", "bc-so"):
        with open(out / "curves" / f"{name}.csv") as f:
            for row in csv.DictReader(f):
                logged.setdefault(row["run"], []).append(float(row["loss"]))
    assert len(logged) == len(r["runs"])
    curves = {json.dumps(run["train_curve"]) for run in r["runs"]}
    assert len(curves) == len(r["runs"])   # no two runs share a curve
    for run in r["runs"]:
        match = [label for label, loss in logged.items() if np.allclose(loss, run["train_curve"], rtol=1e-6)]
        assert len(match) == 1 and run["method"] in match[0] and f"seed{run['seed']}" in match[0]
        assert run["train_loss_final"] == pytest.approx(np.mean(logged[match[0]][-100:]), rel=1e-6)


@pytest.mark.integration
def test_the_printed_table_leads_with_the_tasks_own_metrics(finished):
    _, _, printed = finished
    header = next(line for line in printed.splitlines() if "method" in line and "hparams" in line)
    assert header.index("success") < header.index("red_light_violations") and "return" not in header
    assert "normalized 33.3%" not in printed and "success in % of episodes" in printed
    csv_header = (finished[0] / "results.csv").read_text().splitlines()[0].split(",")
    assert csv_header[4:6] == ["success_mean", "success_std"] and "stuck_mean" in csv_header


@pytest.mark.integration
def test_every_baseline_runs_from_the_sweep_under_its_design_name(tmp_path):
    out = tmp_path / "run"
    argv = ["--env", "toycar", "--obs", "full", "--iterations", "24", "--eval-episodes", "2", "--seeds", "1",
            "--methods", "baselines", "--set", "budget.probe_steps=0", "--out", str(out),
            "--data-dir", str(tmp_path / "data")]
    assert sweep.main(argv) == 0
    r = json.loads((out / "results.json").read_text())
    # the shortcut leaves out channel-dropout (no leaking channel to drop without the previous action in view) and
    # priming (it reads BC-SO's policies, which `baselines` does not bring)
    assert [run["method"] for run in r["runs"]] == [m for m in methods.names("baseline")
                                                    if m not in ("channel-dropout", "priming")]
    assert all(run["status"] == "ok" and run["eval"]["episodes"] == 2 for run in r["runs"]), r["runs"]
    hp = {run["method"]: run["hparams"] for run in r["runs"]}
    car = tasks.get("toycar")
    assert hp["fca"] == {"alpha": car.fca_alpha, "adversary_lr": car.fca_adversary_lr}
    assert hp["bcpd"] == {"thr": 0.1, "w": 5.0}
    assert hp["history-dropout"] == {"p": 0.5} and hp["dagger"]["budget"] == r["config"]["data"]["train_transitions"]
    assert [run["method"] for run in r["runs"] if run["online"]] == ["dagger"]
    assert r["config"]["score_rows"] == ["ape", "actfreq", "bcpd", "kmeans"]
    assert (out / "params" / "h2").is_dir()


@pytest.mark.integration
def test_resume_reports_a_finished_sweep_without_rerunning(finished, capsys):
    out, argv, _ = finished
    assert sweep.main([*argv, "--resume"]) == 0
    assert "not rerunning" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--env", "ant"], "unknown env 'ant' for the sweep"),
    (["--methods", "bc-oh,dagger2"], "unknown method(s) dagger2; valid: bc-so, bc-oh"),
    (["--methods", "bc-oh,bc-oh"], "listed twice"),
    (["--seeds", "0"], "--seeds must be >= 1"),
    (["--preset", "huge"], "invalid choice"),
    (["--env", "toycar", "--obs", "pos"], "not supported by toycar"),
])
def test_sweep_refuses_bad_input_before_compiling(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        sweep.parse(argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.integration
def test_a_diverging_configuration_is_recorded_as_failed_and_the_others_finish(tmp_path):
    out = tmp_path / "run"
    argv = ["--env", "toycar", "--obs", "full", "--iterations", "30", "--eval-episodes", "1",
            "--methods", "bc-oh,ours-step,diverging", "--step-grid", "0.1:3,0.1:5", "--set", "budget.probe_steps=0",
            "--out", str(out), "--data-dir", str(tmp_path / "data")]
    with methods.scratch():   # a method with an absurd learning rate, in the grid program beside the others
        methods.register(methods.Method("diverging", "Diverging", grid=lambda ctx: [{}],
                                        hparams=lambda s, lr, row: Hparams.make("uniform", lr=1e30)))
        assert sweep.main(argv) == 0
    r = json.loads((out / "results.json").read_text())
    failed = [run for run in r["runs"] if run["status"] == "failed"]
    assert [f["method"] for f in failed] == ["diverging"] and "non-finite" in failed[0]["error"]
    assert None in failed[0]["train_curve"]  # NaN windows are null in JSON
    assert sum(run["status"] == "ok" for run in r["runs"]) == 3
    row = next(s for s in r["summary"] if s["method"] == "diverging")
    assert row["n_seeds"] == 0 and row["return_mean"] is None


@pytest.mark.parametrize("argv, message", [
    (["--step-grid", "0.1:0.5"], "--step-grid: W must be a finite number >= 1, got 0.5"),
    (["--step-grid", "1.2:5"], "--step-grid: THR must be in (0, 1), got 1.2"),
    (["--step-grid", "0.1"], "--step-grid: '0.1' is not THR:W"),
    (["--step-grid", "0.1:5,0.1:5"], "--step-grid lists a setting twice"),
    (["--softmax-grid", "0"], "--softmax-grid: tau must be a finite number > 0, got 0"),
    (["--softmax-grid", ","], "--softmax-grid is empty"),
])
def test_custom_grids_are_validated(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        sweep.parse(argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_custom_grids_replace_the_presets_and_name_the_runs():
    from ape_jax.pipeline.sweep import grid_runs

    args = sweep.parse(["--env", "walker2d", "--preset", "default", "--step-grid", "0.1:4,0.1:5,0.1:6",
                        "--softmax-grid", "0.1,0.2,0.5"])
    s = args.settings
    assert s.knob("ours-step").grid == ((0.1, 4.0), (0.1, 5.0), (0.1, 6.0))
    assert s.knob("ours-softmax").taus == (0.1, 0.2, 0.5)
    ctx = methods.GridContext(task=tasks.get("walker2d"), n_train=100, knobs=s.knobs)
    assert methods.get("bcpd").settings(ctx) == [{"thr": 0.1, "w": 5.0}]   # a weighting with a fixed grid keeps it
    runs = grid_runs(("ours-step", "ours-softmax"), 1, ctx)
    assert [r.hparams for r in runs] == [{"thr": 0.1, "w": 4.0}, {"thr": 0.1, "w": 5.0}, {"thr": 0.1, "w": 6.0},
                                         {"tau": 0.1}, {"tau": 0.2}, {"tau": 0.5}]


def test_a_shortcut_leaves_out_what_cannot_run_here_and_a_named_method_is_refused(tmp_path, capsys):
    args = sweep.parse(["--env", "hopper", "--methods", "baselines", "--out", str(tmp_path / "a")], writes=False)
    assert "channel-dropout" not in args.methods and "ptp" in args.methods
    err = capsys.readouterr().err
    assert "leaving out channel-dropout" in err and "protocol.prev_action=true" in err
    # Priming reads BC-SO's policies, which `baselines` does not bring: left out too; `all` brings both
    assert "priming" not in args.methods and "leaving out priming" in err and "add bc-so to --methods" in err
    every = sweep.parse(["--env", "hopper", "--methods", "all", "--out", str(tmp_path / "d")], writes=False)
    assert {"bc-so", "priming"} <= set(every.methods)
    kept = sweep.parse(["--env", "hopper", "--methods", "baselines", "--set", "protocol.prev_action=true",
                        "--out", str(tmp_path / "b")], writes=False)
    assert "channel-dropout" in kept.methods
    named = sweep.parse(["--env", "hopper", "--methods", "bc-oh,channel-dropout", "--out", str(tmp_path / "c")],
                        writes=False)
    assert named.methods == ("bc-oh", "channel-dropout")   # asked for by name: the spec refuses it, in one line
