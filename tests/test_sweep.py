"""The main job end to end on a shrunken preset (ToyCar: no MJX compile), and its refusals."""

import json

import pytest

from ape_jax.pipeline.sweep import SOFTMAX_GRID, STEP_GRID
from experiments import sweep


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    argv = ["--env", "toycar", "--obs", "full", "--iterations", "30", "--eval-episodes", "2", "--seeds", "2",
            "--out", str(out / "run"), "--data-dir", str(out / "data")]
    assert sweep.main(argv) == 0
    return out / "run", argv


def test_sweep_writes_results_matching_the_schema_with_every_configuration_and_seed(finished):
    out, _ = finished
    r = json.loads((out / "results.json").read_text())
    assert r["schema"] == 1 and (r["env"], r["obs"], r["preset"]) == ("toycar", "full", "quick")
    assert set(r) >= {"config", "expert", "runs", "summary", "timing", "system"}
    expected = {("bc-so", ()), ("bc-oh", ())} | {("ours-step", (("thr", t), ("w", w))) for t, w in STEP_GRID} | \
               {("ours-softmax", (("tau", tau),)) for tau in SOFTMAX_GRID}
    seen = {}
    for run in r["runs"]:
        key = (run["method"], tuple(sorted(run["hparams"].items())))
        seen.setdefault(key, set()).add(run["seed"])
        assert run["status"] == "ok" and run["error"] is None
        assert run["eval"]["episodes"] == 2 and {"success", "progress", "stuck", "normalized"} <= set(run["eval"])
        for split in ("train", "val"):
            assert set(run["losses"][split]) == {"unweighted", "changepoint", "copycat"}
    assert set(seen) == expected and all(s == {0, 1} for s in seen.values())
    assert len(r["summary"]) == len(expected) and all(row["n_seeds"] == 2 for row in r["summary"])
    assert r["config"]["iterations"] == 30 and r["config"]["ape_normalization"] == "mean"
    quantiles = r["config"]["ape"]["quantiles"]
    assert len(quantiles) == 101 and quantiles == sorted(quantiles) and quantiles[0] >= 0
    for run in r["runs"]:  # the training curve: 30 iterations in (at most) 100 windows, and the copycat diagnostics
        curve = run["train_curve"]  # one point per iteration here; train_loss_final is the mean of all 30
        assert len(curve) == 30 and sum(curve) / 30 == pytest.approx(run["train_loss_final"], rel=1e-5)
        assert run["eval"]["imitation_error"] >= 0 and run["eval"]["rollout_ape"] >= 0
    assert r["timing"]["total_s"] > 0 and r["system"]["backend"] == "cpu"
    assert (out / "results.csv").read_text().count("\n") == len(expected) + 1
    assert (out / "params" / "h2").is_dir() and (out / "params" / "h1").is_dir()


def test_every_baseline_runs_from_the_sweep_under_its_design_name(tmp_path):
    from ape_jax.pipeline.sweep import METHODS

    out = tmp_path / "run"
    argv = ["--env", "toycar", "--obs", "full", "--iterations", "24", "--eval-episodes", "2", "--seeds", "1",
            "--methods", "baselines", "--out", str(out), "--data-dir", str(tmp_path / "data")]
    assert sweep.main(argv) == 0
    r = json.loads((out / "results.json").read_text())
    baselines = [m for m in METHODS if m not in sweep.DEFAULT_METHODS]
    assert [run["method"] for run in r["runs"]] == baselines
    assert all(run["status"] == "ok" and run["eval"]["episodes"] == 2 for run in r["runs"]), r["runs"]
    hp = {run["method"]: run["hparams"] for run in r["runs"]}
    assert hp["fca"] == {"alpha": 0.2} and hp["bcpd"] == {"thr": 0.1, "w": 5.0} and hp["history-dropout"] == {"p": 0.5}
    assert hp["dagger"]["budget"] == r["config"]["data"]["train_transitions"]
    assert [run["method"] for run in r["runs"] if run["online"]] == ["dagger"]
    assert (out / "params" / "h2").is_dir()


def test_resume_reports_a_finished_sweep_without_rerunning(finished, capsys):
    out, argv = finished
    assert sweep.main([*argv, "--resume"]) == 0
    assert "not rerunning" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--env", "ant"], "unknown env 'ant' for the sweep"),
    (["--methods", "bc-oh,dagger2"], "unknown method(s) ['dagger2']"),
    (["--methods", "bc-oh,bc-oh"], "lists a method twice"),
    (["--seeds", "0"], "--seeds must be >= 1"),
    (["--preset", "huge"], "invalid choice"),
    (["--env", "toycar", "--obs", "pos"], "not supported by toycar"),
])
def test_sweep_refuses_bad_input_before_compiling(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        sweep.parse(argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_a_diverging_configuration_is_recorded_as_failed_and_the_others_finish(tmp_path, monkeypatch):
    from ape_jax.pipeline import sweep as sweep_lib

    real = sweep_lib.hparams_of

    def diverging(run, lr):  # one configuration with an absurd learning rate
        return real(run, 1e30 if run.method == "ours-step" and run.hparams == {"thr": 0.1, "w": 3.0} else lr)

    monkeypatch.setattr(sweep_lib, "hparams_of", diverging)
    out = tmp_path / "run"
    argv = ["--env", "toycar", "--obs", "full", "--iterations", "30", "--eval-episodes", "1",
            "--methods", "bc-oh,ours-step", "--out", str(out), "--data-dir", str(tmp_path / "data")]
    assert sweep.main(argv) == 0
    r = json.loads((out / "results.json").read_text())
    failed = [run for run in r["runs"] if run["status"] == "failed"]
    assert [(f["method"], f["hparams"]) for f in failed] == [("ours-step", {"thr": 0.1, "w": 3.0})]
    assert "non-finite" in failed[0]["error"]
    assert None in failed[0]["train_curve"]  # NaN windows are null in JSON
    assert sum(run["status"] == "ok" for run in r["runs"]) == 6
    row = next(s for s in r["summary"] if s["hparams"] == {"thr": 0.1, "w": 3.0})
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
    p = args.preset_cfg
    assert p.step_grid == ((0.1, 4.0), (0.1, 5.0), (0.1, 6.0)) and p.softmax_grid == (0.1, 0.2, 0.5)
    runs = grid_runs(("ours-step", "ours-softmax"), 1, step_grid=p.step_grid, softmax_grid=p.softmax_grid)
    assert [r.hparams for r in runs] == [{"thr": 0.1, "w": 4.0}, {"thr": 0.1, "w": 5.0}, {"thr": 0.1, "w": 6.0},
                                         {"tau": 0.1}, {"tau": 0.2}, {"tau": 0.5}]
