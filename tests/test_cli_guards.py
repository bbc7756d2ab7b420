"""The sweep's printed output and its last guards: the best marked only where an interval says so, the next
steps, budgets checked before anything runs (overflow, cost), `--resume` on a folder with no sweep, Ctrl-C, a
second sweep into a held folder; the missing test extra, dataset errors, the GIF's permissions, drill's help.

Refusals are `PROG: error: ...` on one line, exit status 2, nothing written. A ToyCar sweep (no MJX compile)
on tiny settings stands in for the real ones.
"""

import json
import os
import pathlib
import shlex
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from ape_jax.pipeline import results
from ape_jax.pipeline.checkpoint import LOCK, LockHeld, OutLock
from experiments import _reference, sweep

ROOT = pathlib.Path(__file__).resolve().parents[1]
FCA_BC = ROOT / "results" / "hopper-pos-fca-rows-default-fca-bc.json"  # BC-SO, BC-OH, Ours (10% x 5), 5 seeds
PROG = "python -m experiments.sweep"
TINY = ["--env", "toycar", "--obs", "full", "--iterations", "4", "--eval-episodes", "2", "--seeds", "1",
        "--methods", "bc-oh", "--set", "budget.probe_steps=0", "--quiet"]


def refused(capsys, call) -> str:
    """The one line `call()` refuses with (exit status 2)."""
    with pytest.raises(SystemExit) as exc:
        call()
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    return err


# -- 1. the printed table --------------------------------------------------------------------------------------------

def _with_returns(returns: dict[str, list[float]]) -> results.Results:
    """The committed Hopper file with each method's per-seed returns replaced (seeds 0..len-1), summary redone."""
    obj = json.loads(FCA_BC.read_text())
    obj["runs"] = [r for r in obj["runs"] if r["seed"] < len(returns[r["method"]])]
    for run in obj["runs"]:
        run["eval"]["return_mean"] = returns[run["method"]][run["seed"]]
    obj["summary"] = results.summarize(obj["runs"])
    return results.Results.from_json(obj)


def _marked(text: str) -> list[str]:
    return [line.split()[1] for line in text.splitlines() if line.startswith("* ")]


def test_the_best_is_marked_only_where_its_95_percent_interval_lies_above_every_other_mean():
    clear = _with_returns({"bc-so": [500, 510, 490, 505, 495], "bc-oh": [1000, 1010, 990, 1005, 995],
                           "ours-step": [900, 950, 850, 920, 880]})
    text = sweep.table(clear)
    assert _marked(text) == ["bc-oh"] and "* = best: its 95% interval over seeds (Student's t)" in text
    # the same means, BC-OH's seeds spread: its interval (1000 ± 2.776 x 158 / sqrt 5 = ± 196) reaches Ours' 900
    close = _with_returns({"bc-so": [500, 510, 490, 505, 495], "bc-oh": [1000, 800, 1200, 1100, 900],
                           "ours-step": [900, 950, 850, 920, 880]})
    text = sweep.table(close)
    assert _marked(text) == [] and "no * (best): no configuration's 95% interval over seeds" in text
    assert "1,000.0 ± 158.1" in text   # the sample sd (ddof 1); the population sd would print 141.4


def test_one_seed_says_no_interval_and_never_plus_minus_zero():
    text = sweep.table(_with_returns({"bc-so": [500], "bc-oh": [1000], "ours-step": [900]}))
    assert _marked(text) == [] and "1 seed: no interval, so none is marked best" in text
    assert "± 0.0" not in text and "(1 seed)" in text


def test_the_sweep_ends_with_the_commands_that_report_its_folder_and_compare_it_where_compare_can(tmp_path):
    import shutil

    shipped = pathlib.Path(__file__).resolve().parent.parent / "results"
    out = tmp_path / "my run"
    out.mkdir()
    shutil.copy(shipped / "hopper-pos-fca-rows-default-fca-after.json", out / "results.json")   # RAP, PALR, MINE
    lines = _reference.next_steps(out)
    assert lines[0] == "next:"
    py = _reference.typed_python()   # `.venv/bin/python` from the clone: the command runs as typed
    assert shlex.split(lines[1].split("#")[0]) == [py, "-m", "experiments.report", f"{out}/results.json",
                                                   "--out", f"{out}/report.md"]
    assert shlex.split(lines[2].split("#")[0]) == [py, "-m", "experiments.compare", str(out)]
    shutil.copy(shipped / "hopper-pos-fca-rows-default-fca-bc.json", out / "results.json")   # references only
    lines = _reference.next_steps(out)
    assert len(lines) == 3 and lines[2].lstrip().startswith("# experiments.compare") and "none here" in lines[2]
    assert "without --smoke" in _reference.next_steps(out, smoke=True)[0]


def test_the_next_commands_name_the_interpreter_a_fresh_shell_can_run(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "executable", str(tmp_path / ".venv" / "bin" / "python"))
    assert _reference.typed_python() == ".venv/bin/python"
    monkeypatch.setattr(sys, "executable", "/usr/bin/python3")
    assert _reference.typed_python() == "python"


# -- 2. ranges, 4. --resume, 5. cost: refused while parsing, before anything runs --------------------------------

@pytest.mark.parametrize("argv, message", [
    (["--iterations", "1000000000000"], "--iterations must be at most 2,147,483,647 (the device counts in 32-bit"),
    (["--seeds", "2147483648"], "--seeds must be at most 2,147,483,647"),
    (["--set", "budget.iterations=3000000000"], "budget.iterations must be an integer >= 1 and <= 2,147,483,647"),
    (["--set", "budget.first_seed=2147483000", "--seeds", "1000"],
     "budget.first_seed + budget.seeds - 1 must be at most 2,147,483,647"),
])
def test_budgets_that_would_overflow_are_refused_before_anything_runs(tmp_path, capsys, argv, message):
    out = tmp_path / "run"
    assert message in refused(capsys, lambda: sweep.main([*argv, "--yes", "--out", str(out)]))
    assert not out.exists()


def test_a_sweep_over_the_cost_limit_is_refused_with_its_estimate_unless_yes(tmp_path, capsys):
    out = tmp_path / "run"
    err = refused(capsys, lambda: sweep.main(["--seeds", "1000000", "--out", str(out)]))
    assert err.startswith(f"{PROG}: error: this sweep asks for 42,000,000,000 model updates (14 configurations x "
                          "1,000,000 seeds x 3,000 iterations) and 70,000,000 evaluation episodes, over the limit of "
                          "1,000,000,000 updates or 1,000,000 episodes; pass --yes")
    assert not out.exists()
    assert "over the limit" in refused(capsys, lambda: sweep.parse(["--eval-episodes", "100000", "--out", str(out)]))
    args = sweep.parse(["--seeds", "1000000", "--yes", "--out", str(out)])
    assert args.cost.over and args.cost.updates == 42_000_000_000


@pytest.mark.parametrize("argv", [
    [],                                                                        # the README's first command
    ["--env", "walker2d", "--preset", "default", "--seeds", "5", "--methods", "bc-so,bc-oh,ours-step,fca,rap,palr"],
    ["--preset", "paper", "--methods", "all"],
])
def test_the_readme_default_and_paper_sweeps_are_far_under_the_cost_limit(tmp_path, argv):
    cost = sweep.parse([*argv, "--out", str(tmp_path / "run")]).cost
    assert cost.updates <= sweep.UPDATES_LIMIT / 20 and cost.episodes <= sweep.EPISODES_LIMIT / 20


def test_resume_refuses_a_folder_with_no_sweep_unless_fresh(tmp_path, capsys):
    for out in (tmp_path / "mistyped", tmp_path / "empty"):
        (tmp_path / "empty").mkdir(exist_ok=True)
        err = refused(capsys, lambda: sweep.parse(["--resume", "--out", str(out)]))
        assert err == (f"{PROG}: error: --resume: {out} holds no sweep to resume (no results.json, no "
                       "checkpoints/sweep.json); check --out, or start a new sweep there with --fresh instead of "
                       "--resume\n")
    assert not (tmp_path / "mistyped").exists() and not any((tmp_path / "empty").iterdir())
    assert sweep.parse(["--fresh", "--out", str(tmp_path / "empty")]).fresh
    # a stopped sweep's checkpoints (the background sweeps' folders: no lock file) resume
    (tmp_path / "stopped" / "checkpoints").mkdir(parents=True)
    (tmp_path / "stopped" / "checkpoints" / "sweep.json").write_text("{}")
    assert sweep.parse(["--resume", "--out", str(tmp_path / "stopped")]).resume
    with pytest.raises(SystemExit):   # both documented in --help
        sweep.parse(["--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "refused where --out holds no sweep (an empty or mistyped folder)" in help_text
    assert "what to pass where --resume finds no sweep to continue" in help_text


# -- 3. Ctrl-C -------------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """ToyCar's demonstrations, collected once for this module."""
    from experiments import collect

    path = tmp_path_factory.mktemp("data")
    assert collect.main(["--env", "toycar", "--obs", "full", "--data-dir", str(path)]) == 0
    return path


@pytest.mark.integration
def test_ctrl_c_mid_sweep_exits_130_with_one_line_on_resuming_and_the_resume_finishes(tmp_path, data_dir, capsys,
                                                                                       monkeypatch):
    from ape_jax.pipeline import sweep as sweep_lib

    out = tmp_path / "run"
    argv = [*TINY, "--out", str(out), "--data-dir", str(data_dir)]

    def interrupt(*args, **kwargs):   # Ctrl-C as training starts, the APE fit saved
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep_lib, "train", interrupt)
    assert sweep.main(argv) == 130
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.strip().count("\n") == 0
    assert err.strip() == (f"{PROG}: interrupted; {out}/checkpoints/ keeps what was saved: resume with --resume and "
                           f"the same --out: {PROG} {' '.join(argv)} --resume")
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["ape.npz", "sweep.json"]
    assert not (out / LOCK).exists()   # released
    monkeypatch.undo()
    assert sweep.main([*argv, "--resume"]) == 0
    printed = capsys.readouterr().out
    assert f"resuming from {out}/checkpoints" in printed and (out / "results.json").is_file()


def test_ctrl_c_before_anything_is_saved_says_so_and_leaves_no_folder(tmp_path, capsys, monkeypatch):
    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep, "_open_out", interrupt)
    out = tmp_path / "run"
    assert sweep.main([*TINY, "--out", str(out)]) == 130
    assert capsys.readouterr().err.strip() == (f"{PROG}: interrupted before anything was saved; run the same "
                                               "command again to start")
    assert not out.exists()


@pytest.mark.slow
def test_a_real_sigint_during_training_leaves_one_line_and_resumable_checkpoints(tmp_path, data_dir):
    out = tmp_path / "run"
    argv = [*TINY[:TINY.index("--iterations")], "--iterations", "100000", "--checkpoint-every", "50",
            *TINY[TINY.index("--iterations") + 2:], "--out", str(out), "--data-dir", str(data_dir)]
    proc = subprocess.Popen([sys.executable, "-m", "experiments.sweep", *argv], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    deadline = time.time() + 300
    while not list((out / "checkpoints").glob("train-*/*")) and time.time() < deadline:
        time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "Traceback" not in err, err[-3000:]
    assert err.strip().splitlines()[-1].startswith(f"{PROG}: interrupted; {out}/checkpoints/ keeps what was saved")
    assert not (out / LOCK).exists()
    from ape_jax.pipeline.checkpoint import ProgramCheckpoint
    saved = [p for p in (out / "checkpoints").glob("train-*") if p.is_dir()]
    assert saved and all(ProgramCheckpoint(p, 50)._manager().latest_step() for p in saved)


def test_a_real_sigint_while_demonstrations_are_collected_stops_the_sweep_within_seconds_caching_nothing(tmp_path):
    """Collection runs in short jitted chunks and compiles in the background: a Ctrl-C is not held for a whole
    batch of episodes or an XLA compile (it took 20-38 s), and it says what it stopped."""
    out, data = tmp_path / "run", tmp_path / "data"
    argv = [*TINY, "--set", "protocol.episodes=100000", "--out", str(out), "--data-dir", str(data)]
    proc = subprocess.Popen([sys.executable, "-u", "-m", "experiments.sweep", *argv], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert proc.stdout.readline().startswith("sweep: toycar")   # printed just before the collection starts
        time.sleep(2.0)   # compiling, or collecting (100,000 ToyCar episodes take minutes)
        proc.send_signal(signal.SIGINT)
        sent = time.monotonic()
        _, err = proc.communicate(timeout=60)
        took = time.monotonic() - sent
    finally:
        proc.kill()
    assert proc.returncode == 130 and "Traceback" not in err, err[-3000:]
    assert took < 5.0, f"the sweep took {took:.1f} s to stop"   # ~1 s, most of it the interpreter's exit
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"{PROG}: interrupted: stopped the collection of 100,000 expert episodes (") and \
        "collected, nothing cached); " in line, line
    assert not list(data.glob("*.npz")) and not (out / LOCK).exists()


# -- 6. a held folder ------------------------------------------------------------------------------------------------

HOLDER = """
import sys, time
from ape_jax.pipeline.checkpoint import OutLock
OutLock(sys.argv[1]).acquire()
print("held", flush=True)
time.sleep(600)
"""


def test_a_second_sweep_into_a_held_folder_is_refused_naming_the_holder_and_a_killed_holder_is_taken_over(
        tmp_path, capsys):
    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], cwd=ROOT, stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline() == "held\n"
        err = refused(capsys, lambda: sweep.main(["--out", str(out)]))
        assert err.startswith(f"{PROG}: error: {out} is in use by another sweep (pid {holder.pid} on "
                              f"{socket.gethostname()}, started 20")
        assert err.endswith("); wait for it to finish, or use another --out\n")
        assert sorted(p.name for p in out.iterdir()) == [LOCK]   # nothing of the second sweep
    finally:
        holder.kill()
        holder.wait()
    stale = (out / LOCK).read_bytes()   # a killed sweep leaves its file, and no lock: taken over
    (out / "checkpoints").mkdir()
    (out / "checkpoints" / "notes.txt").write_text("someone else's")
    err = refused(capsys, lambda: sweep.main([*TINY, "--out", str(out)]))   # taken, then refused: left as found
    assert "is not a checkpoint of this project's sweep" in err and (out / LOCK).read_bytes() == stale
    with OutLock(out):
        record = json.loads((out / LOCK).read_text())
        assert record["pid"] == os.getpid() and record["host"] == socket.gethostname()
    assert not (out / LOCK).exists()


def test_a_lock_left_by_a_killed_sweep_is_taken_over_saying_so_in_one_line(tmp_path, capsys):
    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], cwd=ROOT, stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline() == "held\n"
        started = json.loads((out / LOCK).read_text())["started"]
    finally:
        holder.kill()   # SIGKILL: no chance to release; the kernel drops the flock, the file stays
        holder.wait()
    (out / "checkpoints").mkdir()
    (out / "checkpoints" / "notes.txt").write_text("someone else's")   # so the sweep stops right after the lock
    with pytest.raises(SystemExit):
        sweep.main([*TINY, "--out", str(out)])
    printed = capsys.readouterr().out
    assert printed.splitlines()[0] == (f"took over {out / LOCK}: the sweep that held it (pid {holder.pid} on "
                                       f"{socket.gethostname()}, started {started}) ended without releasing it")


def test_the_lock_is_exclusive_within_one_process_too_and_a_folder_without_one_is_taken(tmp_path):
    (tmp_path / "checkpoints").mkdir()   # a sweep folder from before the lock
    with OutLock(tmp_path):
        with pytest.raises(LockHeld, match=f"pid {os.getpid()} on"):
            OutLock(tmp_path).acquire()
    with OutLock(tmp_path):
        pass


# -- 7. the missing test extra ---------------------------------------------------------------------------------------

def test_run_notebook_without_the_test_extra_names_the_install_command(tmp_path, capsys, monkeypatch):
    from experiments import run_notebook

    notebook = tmp_path / "a.ipynb"
    notebook.write_text("{}")
    monkeypatch.setitem(sys.modules, "nbclient", None)   # as if not installed
    err = refused(capsys, lambda: run_notebook.main([str(notebook)]))
    assert err == ('python -m experiments.run_notebook: error: nbclient is not installed: running notebooks needs '
                   'the test extra, pip install -e ".[test]"\n')


# -- 8. the smaller ones ---------------------------------------------------------------------------------------------

def test_dataset_errors_carry_the_programs_prefix_and_leave_no_folder(tmp_path, capsys):
    out = tmp_path / "run"
    err = refused(capsys, lambda: sweep.main([*TINY, "--dataset", str(tmp_path / "missing.npz"), "--out", str(out)]))
    assert err == f"{PROG}: error: {tmp_path / 'missing.npz'}: no such dataset file\n"
    assert not out.exists()


def test_a_corrupt_npz_without_its_metadata_is_reported_corrupt(tmp_path, capsys):
    from ape_jax.pipeline import data

    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK\x03\x04 not really a zip archive")
    with pytest.raises(data.DataError, match=r"bad.npz: corrupt: not a readable .npz archive \(BadZipFile"):
        data.load(bad)
    np.savez(tmp_path / "good.npz", x=np.zeros(3))   # a readable archive: then the metadata is what is missing
    with pytest.raises(data.DataError, match="its metadata good.json is missing"):
        data.load(tmp_path / "good.npz")
    err = refused(capsys, lambda: sweep.main([*TINY, "--dataset", str(bad), "--out", str(tmp_path / "run")]))
    assert "corrupt" in err and "metadata" not in err


@pytest.mark.parametrize("extra", [["--smoke"], ["--protocol", "brax", "--iterations", "4", "--seeds", "1"]])
def test_a_toycar_dataset_given_to_hopper_is_refused_once_with_one_piece_of_advice(tmp_path, data_dir, capsys,
                                                                                   extra):
    dataset = next(data_dir.glob("toycar-full-*.npz"))
    out = tmp_path / "run"
    err = refused(capsys, lambda: sweep.main(["--env", "hopper", "--dataset", str(dataset), *extra, "--quiet",
                                              "--out", str(out)]))
    assert err == (f"{PROG}: error: {dataset} holds toycar (full) demonstrations, not hopper's; pass --env toycar "
                   "--obs full to train on them\n")
    assert not out.exists()


def test_the_video_gif_gets_the_permissions_of_any_new_file(tmp_path):
    from ape_jax.pipeline import watch

    clip = watch.Clip(frames=np.zeros((2, 8, 8, 3), np.uint8), steps=np.arange(2), rewards=np.ones(2), title="t",
                      episode_return=2.0, mean_return=2.0, metric="return", episode_metric=2.0, mean_metric=2.0,
                      fps=10)
    old = os.umask(0o022)
    try:
        path = watch.write_gif(clip, tmp_path / "videos" / "a.gif")
    finally:
        os.umask(old)
    assert path.read_bytes()[:6] == b"GIF89a" and (path.stat().st_mode & 0o777) == 0o644
    assert [p.name for p in path.parent.iterdir()] == ["a.gif"]   # no temporary left


def test_drill_help_describes_every_option(capsys):
    from experiments import drill

    p = drill.parser()
    assert all(a.help for a in p._actions), [a.dest for a in p._actions if not a.help]
    with pytest.raises(SystemExit) as exc:
        drill.parse(["--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for option in ("--env", "--preset", "--kills", "--kill-every", "--out", "SWEEP_FLAGS"):
        assert option in text


def test_a_fault_inside_a_library_shows_its_traceback_and_a_refusal_of_ours_is_one_line(tmp_path, capsys,
                                                                                       monkeypatch):
    """`_cli.refused`: a `ValueError` raised inside a library (a JAX shape error: a bug, as Priming's stacked weight
    once was) propagates with its traceback, where the project's own `ValueError` is a one-line refusal (exit 2);
    the output folder a sweep made is left as it was found either way."""
    import jax.numpy as jnp

    from ape_jax.pipeline import sweep as pipeline
    from experiments._cli import refused

    def broken(*args, **kwargs):
        return jnp.ones((2, 3)) * jnp.ones(2)

    monkeypatch.setattr(pipeline, "run_sweep", broken)
    argv = ["--env", "toycar", "--obs", "full", "--smoke", "--quiet", "--methods", "bc-so"]
    with pytest.raises(ValueError, match="Incompatible shapes") as e:
        sweep.main([*argv, "--out", str(tmp_path / "a"), "--data-dir", str(tmp_path / "data")])
    assert not refused(e.value) and not (tmp_path / "a").exists()
    with pytest.raises(ValueError) as ours:
        pipeline.SweepSpec("toycar", "full", None, ("no-such-method",))
    assert refused(ours.value)


def test_a_method_the_shortcut_brings_in_with_an_empty_grid_is_not_announced_as_trained(tmp_path, capsys):
    """ToyTown's image presets train the paper's step setting only (`softmax_grid=()`): the no-argument sweep announces
    and runs BC-SO, BC-OH and ours (step), and its header names ours (softmax) as having no setting, instead of
    announcing it as trained; a refusal of the same command stays one line."""
    args = sweep.parse(["--env", "toytown", "--out", str(tmp_path / "run")])
    assert args.methods == ("bc-so", "bc-oh", "ours-step") and args.empty == ("ours-softmax",)
    assert capsys.readouterr().err == ""
    assert "ours-softmax" in sweep.parse(["--env", "hopper", "--out", str(tmp_path / "other")]).methods
    refused(capsys, lambda: sweep.main(["--env", "toytown", "--set", "protocol.traffic=jammed", "--yes",
                                        "--out", str(tmp_path / "bad")]))
