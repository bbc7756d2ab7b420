"""Kill-and-resume and determinism of the sweep, its refusal of checkpoints it cannot resume, and the evaluation
of its saved policies again.

A shrunken ToyCar sweep (state observations: no MJX or convolution compiles)
runs uninterrupted in this process; the same sweep is killed with SIGKILL in a
subprocess at a chosen point, resumed, and must give bit-identical results.
"""

import fcntl
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest

from experiments import sweep

pytestmark = pytest.mark.integration  # end-to-end sweeps: `pytest -m integration`, which CI runs

ROOT = pathlib.Path(__file__).resolve().parents[1]
ARGS = ["--env", "toycar", "--obs", "full", "--iterations", "60", "--checkpoint-every", "20", "--eval-episodes", "2",
        "--seeds", "1", "--methods", "bc-oh,ours-step", "--quiet", "--set", "budget.eval_at=30",
        "--set", "budget.probe_steps=100"]   # the diagnostics' fits shortened (quick's: 500 steps)

# Runs the sweep's command line and SIGKILLs itself right after the KILL_AT-th save of kind KILL_KIND:
# "train" (a training state, orbax) or "phase" (saved arrays: the APE fit, policies kept at eval_at, an evaluation
# group).
KILLER = """
import os, signal, sys
from ape_jax.pipeline import checkpoint
kind, at, count = os.environ["KILL_KIND"], int(os.environ["KILL_AT"]), [0]
cls, name = (checkpoint.ProgramCheckpoint, "save") if kind == "train" else (checkpoint.SweepCheckpoint, "save_arrays")
real = getattr(cls, name)
def save(self, *args, **kwargs):
    real(self, *args, **kwargs)
    count[0] += 1
    if count[0] == at:
        os.kill(os.getpid(), signal.SIGKILL)
setattr(cls, name, save)
from experiments import sweep

sys.exit(sweep.main(sys.argv[1:]))
"""


def numbers(results: dict) -> dict:
    """Everything in results.json but timing, system and command (when, where and how it was started)."""
    return {k: v for k, v in results.items() if k not in ("timing", "system", "command")}


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A directory shared by every pytest-xdist worker of this session (one reference sweep, one dataset)."""
    root = tmp_path_factory.getbasetemp()
    root = root.parent if os.environ.get("PYTEST_XDIST_WORKER") else root
    (root / "resume").mkdir(exist_ok=True)
    return root / "resume"


@pytest.fixture(scope="module")
def reference(workdir):
    """The uninterrupted sweep's results, run once per session by whichever worker asks first (which also
    collects the dataset every test here shares, before any other test can)."""
    out = workdir / "reference"
    with open(workdir / "reference.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (out / "results.json").exists():
            assert sweep.main([*ARGS, "--out", str(out), "--data-dir", str(workdir / "data")]) == 0
    return json.loads((out / "results.json").read_text())


def killed_run(workdir, name, kind, at) -> pathlib.Path:
    out = workdir / name
    env = {**os.environ, "KILL_KIND": kind, "KILL_AT": str(at), "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-c", KILLER, *ARGS, "--out", str(out), "--data-dir", str(workdir / "data")],
                          env=env, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    assert not (out / "results.json").exists()
    return out


def resume(workdir, out, capsys) -> dict:
    assert sweep.main([*ARGS, "--out", str(out), "--data-dir", str(workdir / "data")]) == 0
    captured = capsys.readouterr()
    assert "resuming from" in captured.out and "it/s" not in captured.err  # --quiet: no progress bars
    assert not (out / "checkpoints").exists()  # cleared once the outputs are written
    return json.loads((out / "results.json").read_text())


def test_a_sweep_killed_mid_training_and_resumed_equals_an_uninterrupted_one_bit_for_bit(workdir, reference, capsys):
    out = killed_run(workdir, "killed-training", "train", 2)
    steps = sorted(int(p.name) for p in (out / "checkpoints" / "train-grid").iterdir() if p.name.isdigit())
    assert steps == [40]  # killed where we meant to: BC-OH and the step grid at 40 of 60 iterations
    assert (out / "checkpoints" / "train-grid-at30.npz").exists()  # the policies at eval_at, kept when passed
    # the curves were written while it trained: every iteration up to the kill, and a TensorBoard run per configuration
    live = (out / "curves" / "grid.csv").read_text().splitlines()
    assert len(live) == 1 + 7 * 40 and len(list((out / "tensorboard").iterdir())) == 7
    resumed = resume(workdir, out, capsys)
    assert all([a["iteration"] for a in r["at"]] == [30] for r in resumed["runs"])
    assert resumed["timing"]["resumed"] and not reference["timing"]["resumed"]
    assert numbers(resumed) == numbers(reference)
    curves = (out / "curves" / "grid.csv").read_text().splitlines()
    assert len(curves) == 1 + 7 * 60  # every iteration of BC-OH and the six step configurations, once
    assert len(list((out / "tensorboard").iterdir())) == 7


def test_the_same_sweep_in_another_process_gives_bit_identical_numbers(workdir, reference, capsys):
    """Determinism: a second process computes everything (killed after its last phase, before writing the
    outputs); resuming only writes what it computed, and that equals the reference run's numbers."""
    # saved arrays: the APE fit, the policies at eval_at, the evaluation at the end and at eval_at
    out = killed_run(workdir, "killed-at-the-end", "phase", 4)
    assert (out / "checkpoints" / "eval-h2.npz").exists() and (out / "checkpoints" / "eval-h2-at30.npz").exists()
    again = resume(workdir, out, capsys)
    assert again["timing"]["train_s"] == again["timing"]["eval_s"] == 0.0  # nothing recomputed here
    assert numbers(again) == numbers(reference)
    assert len({r["train_loss_final"] for r in again["runs"]}) == len(again["runs"])  # not trivially equal


def refused(argv, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        sweep.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


def snapshot(path: pathlib.Path) -> dict:
    return {p.relative_to(path): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def test_checkpoints_it_cannot_resume_are_refused_and_left_alone(workdir, reference, capsys):
    out = killed_run(workdir, "killed-early", "train", 1)  # APE fitted, the grid at 20 of 60 iterations
    before = snapshot(out)
    data = ["--data-dir", str(workdir / "data")]
    other = [*ARGS[:ARGS.index("--seeds")], "--seeds", "2", *ARGS[ARGS.index("--seeds") + 2:]]
    assert "holds a checkpoint of a different sweep, differing in settings.budget.seeds (1 there, 2 now)" in \
        refused([*other, "--out", str(out), *data], capsys)
    assert snapshot(out) == before

    foreign = workdir / "foreign"
    (foreign / "checkpoints").mkdir(parents=True)
    (foreign / "checkpoints" / "notes.txt").write_text("someone else's")
    assert "is not a checkpoint of this project's sweep" in refused([*ARGS, "--out", str(foreign), *data], capsys)
    assert (foreign / "checkpoints" / "notes.txt").read_text() == "someone else's"

    corrupt = workdir / "corrupt-phase"
    shutil.copytree(out, corrupt)
    (corrupt / "checkpoints" / "ape.npz").write_bytes(b"PK\x03\x04 truncated")
    assert "ape.npz is unreadable" in refused([*ARGS, "--out", str(corrupt), *data], capsys)

    damaged = workdir / "damaged-state"
    shutil.copytree(out, damaged)
    step = damaged / "checkpoints" / "train-grid" / "20"
    for f in (p for p in (step / "state").rglob("*") if p.is_file() and p.stat().st_size > 0):
        f.write_bytes(b"\0" * 16)
    before = snapshot(damaged)
    assert "train-grid is unreadable or not this sweep's training state" in \
        refused([*ARGS, "--out", str(damaged), *data], capsys)
    assert snapshot(damaged) == before


def test_a_finished_sweep_is_reported_or_refused_never_overwritten(workdir, reference, capsys):
    out = workdir / "reference"
    data = ["--data-dir", str(workdir / "data")]
    assert sweep.main([*ARGS, "--out", str(out), *data]) == 0
    assert "already holds this sweep; not rerunning" in capsys.readouterr().out
    other = [*ARGS[:ARGS.index("--iterations")], "--iterations", "40", *ARGS[ARGS.index("--iterations") + 2:]]
    before = snapshot(out)
    assert "holds a finished sweep with other settings, differing in settings.budget.iterations (60 there, 40 now)" in \
        refused([*other, "--out", str(out), *data], capsys)
    assert snapshot(out) == before


@pytest.mark.parametrize("argv, message", [
    (["--resume", "--fresh"], "--resume and --fresh contradict each other"),
    (["--checkpoint-every", "0"], "--checkpoint-every must be >= 1"),
])
def test_contradictory_or_out_of_range_resume_options_are_refused(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        sweep.parse(argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_an_output_directory_that_cannot_be_written_is_refused_before_any_work(tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    with pytest.raises(SystemExit) as exc:
        sweep.parse(["--out", str(blocker / "run")])
    assert exc.value.code == 2 and "a-file is not a directory" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        sweep.parse(["--out", str(blocker)])
    assert exc.value.code == 2 and "exists and is not a directory" in capsys.readouterr().err
    assert blocker.read_text() == "not a directory"


def test_a_sweep_from_the_minari_export_of_its_demonstrations_gives_the_same_numbers(workdir, reference, tmp_path):
    """`--dataset` on a Minari dataset: the same episodes as the collected ones, so the same results, bit for bit."""
    from ape_jax.pipeline import data, minari_io

    collected = pathlib.Path(reference["config"]["data"]["path"])
    demos, meta = data.load(collected)
    path = minari_io.to_minari(demos, meta, "toycar-full-v0", root=tmp_path / "minari")
    out = tmp_path / "from-minari"
    assert sweep.main([*ARGS, "--dataset", str(path), "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["config"]["data"]["settings"]["dataset"] == str(path.absolute())
    assert results["config"].pop("data")["train_transitions"] == reference["config"]["data"]["train_transitions"]
    # the dataset names the expert that collected it, which a collected sweep records in its data settings
    assert results["expert"].pop("demonstrator") == reference["config"]["data"]["settings"]["expert"]
    assert numbers(results) == numbers({**reference, "config": {k: v for k, v in reference["config"].items()
                                                                 if k != "data"}})


def test_a_dataset_that_does_not_fit_the_environment_is_refused(workdir, reference, capsys):
    collected = reference["config"]["data"]["path"]
    image = [*ARGS[:ARGS.index("--obs")], "--obs", "image", *ARGS[ARGS.index("--obs") + 2:]]
    err = refused([*image, "--dataset", collected, "--out", str(workdir / "misfit")], capsys)
    # its metadata names its observations: refused before its shapes are read, with the flag that fits it
    assert "holds toycar demonstrations observed as 'full', not 'image'; pass --obs full to train on them" in err
    assert not (workdir / "misfit").exists()  # nothing left behind


def test_evaluating_saved_policies_again_adds_the_missing_fields_and_refuses_other_returns(workdir, reference,
                                                                                         tmp_path, capsys):
    """`experiments.evaluate` on a results file stripped of the diagnostics restores them from params/; a file whose
    returns are not the policies' own is refused and left as it was."""
    import copy

    from experiments import evaluate

    run = tmp_path / "run"
    shutil.copytree(workdir / "reference" / "params", run / "params")
    stripped = copy.deepcopy(reference)
    for r in stripped["runs"]:
        del r["eval"]["imitation_error"], r["eval"]["rollout_ape"], r["diagnostics"]
    del stripped["config"]["ape"]["quantiles"], stripped["config"]["ape"]["val_mean"], stripped["config"]["diagnostics"]
    earlier = {"fields": ["config.ape.raw_mean"], "eval_s": 1.0, "diagnostics_s": 0.0, "system": {"commit": "abc1234"}}
    (run / "results.json").write_text(json.dumps({**stripped, "reevaluated": earlier}))
    assert evaluate.main([str(run), "--data-dir", str(workdir / "data")]) == 0
    again = json.loads((run / "results.json").read_text())
    assert set(again["reevaluated"]["fields"]) == {"imitation_error", "rollout_ape", "config.ape.quantiles",
                                                   "config.ape.val_mean", "diagnostics", "config.diagnostics"}
    assert again["reevaluated"]["previous"] == earlier  # an earlier evaluation's record is kept
    assert again["config"]["diagnostics"] == reference["config"]["diagnostics"]
    for r, ref in zip(again["runs"], reference["runs"]):
        assert r["eval"] == pytest.approx(ref["eval"], rel=1e-6)
        exact = {k for k, v in ref["diagnostics"].items() if not isinstance(v, float)}  # the verdict, nulls, counts
        assert {k: r["diagnostics"][k] for k in exact} == {k: ref["diagnostics"][k] for k in exact}
        assert {k: v for k, v in r["diagnostics"].items() if k not in exact} == pytest.approx(
            {k: v for k, v in ref["diagnostics"].items() if k not in exact}, rel=1e-5, abs=1e-7)
    ape, ref_ape = again["config"]["ape"], reference["config"]["ape"]
    assert ape["quantiles"] == pytest.approx(ref_ape["quantiles"], rel=1e-6)
    assert ape["val_mean"] == pytest.approx(ref_ape["val_mean"], rel=1e-6)

    stripped["runs"][0]["eval"]["return_mean"] += 1.0
    (run / "results.json").write_text(json.dumps(stripped))
    before = (run / "results.json").read_bytes()
    with pytest.raises(SystemExit) as e:
        evaluate.main([str(run), "--data-dir", str(workdir / "data")])
    assert e.value.code == 2
    assert "differ from the recomputed ones (e.g. bc-oh {} seed 0 return_mean" in capsys.readouterr().err
    assert (run / "results.json").read_bytes() == before
    # demonstrations collected again with the same settings are other data: refused before anything is evaluated
    recollected = copy.deepcopy(reference)
    recollected["config"]["data"]["sha256"] = "0" * 64
    (run / "results.json").write_text(json.dumps(recollected))
    before = (run / "results.json").read_bytes()
    with pytest.raises(SystemExit) as e:
        evaluate.main([str(run), "--data-dir", str(workdir / "data")])
    assert e.value.code == 2 and "are not the sweep's (their SHA-256 differs" in capsys.readouterr().err
    assert (run / "results.json").read_bytes() == before
    # ToyCar's reward is 0 everywhere: its driving metrics are checked too
    stripped["runs"][0]["eval"]["return_mean"] -= 1.0
    stripped["runs"][1]["eval"]["progress"] += 0.5
    (run / "results.json").write_text(json.dumps(stripped))
    with pytest.raises(SystemExit):
        evaluate.main([str(run), "--data-dir", str(workdir / "data")])
    assert "progress" in capsys.readouterr().err
    # diagnostics from before the later fields get them added, the recorded ones checked as they are recomputed
    older = copy.deepcopy(reference)
    for r in older["runs"]:
        del r["diagnostics"]["prev_from_state"], r["diagnostics"]["state_ratio"]
    older["runs"][0]["diagnostics"]["embedding_ratio"] *= 2
    (run / "results.json").write_text(json.dumps(older))
    with pytest.raises(SystemExit):
        evaluate.main([str(run), "--data-dir", str(workdir / "data")])
    assert "seed 0 diagnostics embedding_ratio" in capsys.readouterr().err


def test_a_sweep_trained_again_replaces_a_file_whose_policies_were_not_kept(workdir, reference, tmp_path, capsys):
    """`experiments.evaluate RUN --replaces FILE`: RUN's policies evaluated (its returns must come out again), its
    results written over FILE with FILE's own record kept under `replaces`; a RUN of another sweep is refused in one
    line and FILE left as it was."""
    import copy

    from experiments import evaluate

    run = tmp_path / "run"
    shutil.copytree(workdir / "reference" / "params", run / "params")
    (run / "results.json").write_text(json.dumps(reference))
    kept = (run / "results.json").read_bytes()
    first = copy.deepcopy(reference)   # the first training: other numbers, no diagnostics, no policies
    for r in first["runs"]:
        r["eval"]["return_mean"] += 3.0
        del r["diagnostics"]
    for row in first["summary"]:
        row["return_mean"] += 3.0
    first["system"] = {**first["system"], "commit": "f4e2e9a"}
    old = tmp_path / "results" / "toycar-full-default.json"
    old.parent.mkdir()
    old.write_text(json.dumps(first))
    assert evaluate.main([str(run), "--replaces", str(old), "--data-dir", str(workdir / "data")]) == 0
    printed = capsys.readouterr().out
    assert "first training (commit f4e2e9a) -> trained again:" in printed
    row = reference["summary"][0]
    assert f"{row['return_mean'] + 3.0:,.1f} -> {row['return_mean']:,.1f}" in printed
    assert (run / "results.json").read_bytes() == kept              # RUN's own file is left alone
    now = json.loads(old.read_text())
    assert numbers({k: v for k, v in now.items() if k not in ("reevaluated", "replaces")}) == numbers(reference)
    assert now["replaces"]["file"] == old.name and now["replaces"]["system"]["commit"] == "f4e2e9a"
    assert now["replaces"]["summary"] == first["summary"] and now["replaces"]["command"] == first["command"]
    assert [r["return_mean"] for r in now["replaces"]["runs"]] == [r["eval"]["return_mean"] for r in first["runs"]]
    assert now["reevaluated"]["fields"] == []   # nothing was missing: the retrained sweep has its diagnostics
    # a file that is not RUN's sweep (another budget) is refused, and left as it was
    other = copy.deepcopy(first)
    other["config"]["iterations"] = 90
    old.write_text(json.dumps(other))
    before = old.read_bytes()
    with pytest.raises(SystemExit) as e:
        evaluate.main([str(run), "--replaces", str(old), "--data-dir", str(workdir / "data")])
    assert e.value.code == 2
    assert f"is not {old}'s sweep trained again: iterations 90 against 60" in capsys.readouterr().err
    assert old.read_bytes() == before
    with pytest.raises(SystemExit):   # nor may it replace itself
        evaluate.main([str(run), "--replaces", str(run / "results.json")])
    assert "--replaces names RUN's own results" in capsys.readouterr().err


def test_a_saved_policy_is_watched_as_a_captioned_gif_of_its_evaluation_episode(workdir, reference, tmp_path, capsys):
    """`experiments.evaluate RUN --video METHOD[:SEED]`: a GIF of one of the policy's evaluation episodes, the same
    episodes the sweep evaluated (their mean metric is the recorded one), captioned; bad choices are refused in
    one line, and results.json is left alone."""
    from PIL import Image

    from experiments import evaluate

    run = tmp_path / "run"
    shutil.copytree(workdir / "reference" / "params", run / "params")
    shutil.copy(workdir / "reference" / "results.json", run / "results.json")
    before = (run / "results.json").read_bytes()
    data = ["--data-dir", str(workdir / "data")]
    assert evaluate.main([str(run), "--video", "ours-step:0", "--episode", "1", *data]) == 0
    out = capsys.readouterr().out
    gif = run / "videos" / "ours-step-seed0-episode1.gif"
    assert f"wrote {gif}" in out and (run / "results.json").read_bytes() == before
    recorded = [r for r in reference["runs"] if r["method"] == "ours-step" and r["seed"] == 0]
    best = max(recorded, key=lambda r: r["eval"]["success"])   # one seed: the best setting is its best run
    assert f"thr {best['hparams']['thr']:g}" in out
    mean = float(out.split("the evaluation's mean ")[1].split(")")[0])
    assert mean == pytest.approx(best["eval"]["success"], abs=1e-3)   # ToyCar is judged by success
    with Image.open(gif) as im:
        assert im.n_frames > 10 and im.width == 256 and im.height > 256   # a caption below the frame
        im.seek(im.n_frames // 2)
        frame = np.asarray(im.convert("RGB"))
    assert frame[:256].std() > 5 and (frame[256:] < 100).any()   # a picture, and dark caption text
    # the expert beside the policy, on the same episode: ToyCar's 0.1 s steps at 10 frames per second
    assert evaluate.main([str(run), "--video", "ours-step:0,expert", "--episode", "1", *data]) == 0
    out = capsys.readouterr().out
    both = run / "videos" / "ours-step-seed0+expert-episode1.gif"
    assert f"wrote {both}" in out and "expert, episode 1" in out and "at 10 per second (every step" in out
    with Image.open(both) as im:
        assert im.width == 2 * 256 + 4 and im.info["duration"] == 100
    for argv, message in ((["--video", "nope"], "no trained policy of method 'nope' in this sweep; it ran: "
                                                "bc-oh, ours-step"),
                          (["--video", "bc-oh:7"], "has no seed 7"),
                          (["--video", "bc-oh:x"], "must be an integer"),
                          (["--video", "bc-oh,bc-oh"], "each policy once"),
                          (["--video", "expert:0"], "the expert has no seed"),
                          (["--video", "bc-oh", "--episode", "5"], "episode 5 is not one of the evaluation's 2"),
                          (["--video", "bc-oh", "--video-out", str(tmp_path / "a.mp4")], "must name a .gif"),
                          (["--episode", "1"], "go with --video")):
        with pytest.raises(SystemExit) as e:
            evaluate.main([str(run), *argv, *data])
        assert e.value.code == 2 and message in capsys.readouterr().err, argv
    assert (run / "results.json").read_bytes() == before
