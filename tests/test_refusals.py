"""Input refused in the words of what is wrong, before anything is written, and a Ctrl-C that is never lost.

Each refusal: exit status 2, one line `PROG: error: ...` on stderr, no traceback, no file or folder left. The
paths every entry point takes are tried missing, as a folder where a file is expected, as a file where a folder is,
and truncated; each message says which. Ctrl-C: one that lands where Python ignores exceptions (a `gc.callbacks`
function, as JAX's `_xla_gc_callback`) still stops the sweep with exit status 130 and writes no results.
"""

import gc
import json
import pathlib
import pickle
import signal
import sys

import numpy as np
import pytest

from experiments import _cli, collect, import_expert, report, sweep

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results" / "hopper-pos-fca-rows-default-fca-bc.json"
SWEEP = "python -m experiments.sweep"
TINY = ["--env", "toycar", "--obs", "full", "--iterations", "4", "--eval-episodes", "2", "--seeds", "1",
        "--methods", "bc-oh", "--set", "budget.probe_steps=0", "--quiet"]


def refused(capsys, call) -> str:
    """The one line `call()` refuses with (exit status 2, no traceback)."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        call()
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    return err


def truncated(path: pathlib.Path) -> pathlib.Path:
    """`path` cut to the first half of its bytes, as a copy that stopped midway."""
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])
    return path


# -- 1. tracebacks that were ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("data_dir, message", [
    ("file", "--data-dir {root}/file is a file; it must be a directory"),
    ("file/sub", "--data-dir {root}/file/sub: cannot save the demonstrations to be collected there: {root}/file is "
                 "not a directory"),
])
def test_the_sweep_refuses_a_data_dir_that_is_a_file_before_writing_anything(tmp_path, capsys, data_dir, message):
    (tmp_path / "file").write_text("not a folder")
    out = tmp_path / "run"
    err = refused(capsys, lambda: sweep.main([*TINY, "--data-dir", str(tmp_path / data_dir), "--out", str(out)]))
    assert err == f"{SWEEP}: error: {message.format(root=tmp_path)}\n"
    assert not out.exists()   # no checkpoints/sweep.json left behind, no folder


@pytest.mark.skipif(not pathlib.Path("/proc").is_dir(), reason="needs /proc (Linux): unwritable even for root")
def test_the_sweep_refuses_a_data_dir_it_must_collect_into_but_cannot_write(tmp_path, capsys):
    out = tmp_path / "run"
    err = refused(capsys, lambda: sweep.main([*TINY, "--data-dir", "/proc/ape-jax-data", "--out", str(out)]))
    assert err.startswith(f"{SWEEP}: error: --data-dir /proc/ape-jax-data: cannot save the demonstrations to be "
                          "collected there: /proc is not writable")
    assert not out.exists()


def _expert_npz(path: pathlib.Path) -> pathlib.Path:
    rng = np.random.default_rng(0)
    np.savez(path, obs_mean=rng.normal(size=11), obs_std=np.ones(11), activation=np.array("tanh"),
             head=np.array("linear"), kernel_0=rng.normal(size=(11, 64)), bias_0=np.zeros(64),
             kernel_1=rng.normal(size=(64, 3)), bias_1=np.zeros(3))
    return path


def _expert_pickle(path: pathlib.Path) -> pathlib.Path:
    path.write_bytes(pickle.dumps({"nonlin_type": "tanh", "w": np.arange(200.0)}, protocol=2))
    return path


def _bytes(path: pathlib.Path, raw: bytes) -> pathlib.Path:
    path.write_bytes(raw)
    return path


def _folder(path: pathlib.Path) -> pathlib.Path:
    path.mkdir()
    return path


@pytest.mark.parametrize("make, message", [
    (lambda root: truncated(_expert_npz(root / "e.npz")),
     "{root}/e.npz: not a readable .npz file, truncated or corrupt (BadZipFile: File is not a zip file)"),
    (lambda root: truncated(_expert_pickle(root / "e.pkl")),
     "{root}/e.pkl: not a readable pickle, truncated or corrupt (pickle data was truncated)"),
    (lambda root: _bytes(root / "e.pkl", b"\x00\x01 no pickle at all"),
     "{root}/e.pkl: not a readable pickle, truncated or corrupt (invalid load key"),
    (lambda root: _folder(root / "e.pkl"),
     "{root}/e.pkl is a folder, not an expert file (a CS294 pickle or an .npz MLP)"),
    (lambda root: root / "missing.pkl", "{root}/missing.pkl does not exist"),
])
def test_import_expert_refuses_a_truncated_or_corrupt_file_naming_what_is_wrong(tmp_path, capsys, monkeypatch, make,
                                                                                 message):
    experts_dir = tmp_path / "experts"
    monkeypatch.setenv("APE_JAX_EXPERTS", str(experts_dir))
    path = make(tmp_path)
    err = refused(capsys, lambda: import_expert.main([str(path), "--env", "hopper", "--name", "x"]))
    assert err.startswith(f"python -m experiments.import_expert: error: {message.format(root=tmp_path)}"), err
    assert "refused: only numpy arrays" not in err   # no pickle was refused for what it holds: its bytes are bad
    assert not experts_dir.exists()


# -- 2. silent acceptances that were --------------------------------------------------------------------------------

@pytest.mark.parametrize("episodes, message", [
    ("1000000000000", "--episodes must be at most 2,147,483,647 (episodes are numbered in 32-bit integers), got "
                      "1,000,000,000,000"),
    ("2000000", "--episodes 2,000,000 is over the limit of 1,000,000 episodes (every step is kept in memory and on "
                "disk); pass --yes to collect them anyway, or ask for fewer"),
])
def test_collect_refuses_absurd_amounts_with_the_sweeps_episode_limit(tmp_path, capsys, episodes, message):
    data_dir = tmp_path / "data"
    err = refused(capsys, lambda: collect.main(["--env", "toycar", "--episodes", episodes,
                                                "--data-dir", str(data_dir)]))
    assert err == f"python -m experiments.collect: error: {message}\n"
    assert not data_dir.exists()
    assert _cli.EPISODES_LIMIT == sweep.EPISODES_LIMIT == 1_000_000   # one limit, the sweep's
    args = collect.parse(["--env", "toycar", "--episodes", "2000000", "--yes", "--data-dir", str(data_dir)])
    assert args.episodes == 2_000_000 and not data_dir.exists()   # --yes: accepted (parsing collects nothing)


def test_the_report_and_compare_refuse_a_results_file_with_no_runs(tmp_path, capsys):
    from experiments import compare

    obj = json.loads(RESULTS.read_text())
    assert obj["runs"] and obj["summary"]
    obj["runs"] = []   # the summary alone is left: the numbers it would print back nothing
    empty = tmp_path / "empty.json"
    empty.write_text(json.dumps(obj))
    message = (f"{empty}: the file has no runs (its \"runs\" list is empty), so it has no numbers to report; give a "
               "results.json that experiments.sweep finished\n")
    err = refused(capsys, lambda: report.main([str(empty)]))
    assert err == f"python -m experiments.report: error: {message}"
    err = refused(capsys, lambda: report.main([str(empty), "--out", str(tmp_path / "out" / "BENCHMARKS.md")]))
    assert err == f"python -m experiments.report: error: {message}"
    err = refused(capsys, lambda: compare.main([str(empty), "--against", str(RESULTS),
                                                "--out", str(tmp_path / "out")]))
    assert err == f"python -m experiments.compare: error: {message}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.json"]


# -- 3. refusals in the words of what is wrong ------------------------------------------------------------------------

def _entry(name):
    import importlib

    return importlib.import_module(f"experiments.{name}").main


@pytest.mark.parametrize("name, argv, message", [
    ("report", ["{root}/folder"], "{root}/folder is a folder, not a results file"),
    ("report", ["{root}/missing.json"], "{root}/missing.json: cannot read ([Errno 2] No such file or directory"),
    ("compare", ["{root}/file"], "{root}/file: not valid JSON"),
    ("evaluate", ["{root}/file"], "{root}/file is a file, not a sweep's --out folder: RUN must be a finished sweep's"),
    ("evaluate", ["{root}/missing"], "{root}/missing does not exist: RUN must be a finished sweep's --out directory"),
    ("evaluate", ["--rejudge", "{root}/folder"], "{root}/folder is a folder, not a results file"),
    ("compare_runs", ["{root}/file", "{root}/folder"], "{root}/file is a file, not a sweep's --out folder"),
    ("compare_runs", ["{root}/missing", "{root}/folder"], "{root}/missing does not exist"),
    ("expert_stats", ["--dir", "{root}/file", "--out", "{root}/s.json"],
     "--dir {root}/file is a file, not an expert's folder"),
    ("expert_stats", ["--dir", "{root}/missing", "--out", "{root}/s.json"], "--dir {root}/missing does not exist"),
    ("run_notebook", ["{root}/folder"], "{root}/folder is a folder, not a notebook file"),
    ("weights", ["--dataset", "{root}/folder.npz", "--out", "{root}/w.npz"],
     "{root}/folder.npz is a folder, not a dataset file"),
    ("sweep", [*TINY, "--dataset", "{root}/folder.npz", "--out", "{root}/run"],
     "{root}/folder.npz is a folder, not a dataset file"),
    ("sweep", [*TINY, "--plugins", "{root}/my_plugin.py", "--out", "{root}/run"],
     "--plugins {root}/my_plugin.py: a file path; give the module's name (my_plugin for my_plugin.py"),
    ("pose_probe", ["--out", "{root}/p.json", "--data-dir", "{root}/file"],
     "--data-dir {root}/file is a file; it must be a directory"),
    ("bench_train", ["--results", "{root}/folder"], "--results {root}/folder is a folder, not a results file"),
])
def test_each_path_refusal_says_what_is_actually_wrong(tmp_path, capsys, name, argv, message):
    (tmp_path / "folder").mkdir()
    (tmp_path / "folder.npz").mkdir()
    (tmp_path / "file").write_text("not json")
    before = sorted(tmp_path.rglob("*"))
    err = refused(capsys, lambda: _entry(name)([a.format(root=tmp_path) for a in argv]))
    assert err.startswith(f"python -m experiments.{name}: error: {message.format(root=tmp_path)}"), err
    assert sorted(tmp_path.rglob("*")) == before   # nothing written


def test_the_shared_path_checks_say_what_is_wrong(tmp_path):
    (tmp_path / "file").write_text("x")
    assert _cli.unreadable(tmp_path / "file", "a results file") is None
    assert _cli.unreadable(tmp_path, "a results file") == f"{tmp_path} is a folder, not a results file"
    assert _cli.unreadable(tmp_path / "no", "a results file") == f"{tmp_path}/no does not exist"
    assert _cli.unreadable(tmp_path / "file" / "x.json", "a results file") == (
        f"{tmp_path}/file/x.json does not exist ({tmp_path}/file is a file, not a folder)")
    assert _cli.not_a_folder(tmp_path, "a sweep's --out folder") is None
    assert _cli.not_a_folder(tmp_path / "file", "a sweep's --out folder") == (
        f"{tmp_path}/file is a file, not a sweep's --out folder")
    assert _cli.not_a_folder(tmp_path / "no", "a sweep's --out folder") == f"{tmp_path}/no does not exist"


# -- 4. Ctrl-C ------------------------------------------------------------------------------------------------------

class _Bar:
    """A progress bar that records its updates."""

    def __init__(self, updates, **kwargs):
        self.updates, self.total = updates, kwargs.get("total")

    @classmethod
    def recording(cls, updates):
        return lambda **kw: cls(updates, **kw)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, n=1):
        self.updates.append(n)


def _sigint_in_gc_callback(armed: list):
    """A gc callback (as JAX's `_xla_gc_callback`) during which SIGINT arrives, once, when `armed`."""
    def callback(phase, info):
        if armed and phase == "start":
            armed.clear()
            signal.raise_signal(signal.SIGINT)   # handled here, inside the callback: Python ignores what it raises
    return callback


def test_a_ctrl_c_python_ignores_in_a_gc_callback_is_recorded_and_raised_at_the_next_check(capsys):
    armed = [True]
    callback = _sigint_in_gc_callback(armed)
    handler, hook = signal.getsignal(signal.SIGINT), sys.unraisablehook
    gc.callbacks.append(callback)
    try:
        with _cli.interrupts():
            gc.collect()   # the KeyboardInterrupt raised in the callback goes nowhere...
            assert not armed
            with pytest.raises(KeyboardInterrupt):
                _cli.raise_if_interrupted()   # ...but is raised at the next safe point
            updates = []
            with _cli.checked_bar(_Bar.recording(updates))(desc="train", total=2) as bar:
                with pytest.raises(KeyboardInterrupt):
                    bar.update(1)   # a bar's update is such a point: between chunks
            assert updates == [] and bar.total == 2
    finally:
        gc.callbacks.remove(callback)
    assert "Exception ignored" not in capsys.readouterr().err   # recorded, not reported
    assert signal.getsignal(signal.SIGINT) is handler and sys.unraisablehook is hook   # restored
    _cli.raise_if_interrupted()   # cleared on leaving


@pytest.fixture(scope="module")
def toycar_data(tmp_path_factory):
    path = tmp_path_factory.mktemp("data")
    assert collect.main(["--env", "toycar", "--obs", "full", "--data-dir", str(path)]) == 0
    return path


def test_a_ctrl_c_landing_in_a_gc_callback_stops_the_sweep_with_130_and_no_results(tmp_path, toycar_data, capsys,
                                                                                    monkeypatch):
    """The Ctrl-C that was swallowed one time in five: it arrived while JAX's gc callback ran, Python printed
    "Exception ignored in: <function _xla_gc_callback ...> KeyboardInterrupt", and the sweep finished (exit 0,
    results written). Here it arrives, deterministically, inside a gc callback as training starts."""
    from ape_jax.pipeline import sweep as sweep_lib

    armed: list = []
    real_train = sweep_lib.train

    def train(*args, **kwargs):
        armed.append(True)
        gc.collect()   # a collection as training starts; the SIGINT lands inside its callback
        assert not armed
        return real_train(*args, **kwargs)

    monkeypatch.setattr(sweep_lib, "train", train)
    callback = _sigint_in_gc_callback(armed)
    handler = signal.getsignal(signal.SIGINT)
    gc.callbacks.append(callback)
    out = tmp_path / "run"
    try:
        code = sweep.main([*TINY, "--out", str(out), "--data-dir", str(toycar_data)])
    finally:
        gc.callbacks.remove(callback)
    err = capsys.readouterr().err.strip()
    assert code == 130, err
    assert err.count("\n") == 0 and err.startswith(f"{SWEEP}: interrupted"), err
    assert "Exception ignored" not in err and "Traceback" not in err
    assert not (out / "results.json").exists() and not (out / "params").exists()
    assert signal.getsignal(signal.SIGINT) is handler   # the sweep's own handler is gone again


def test_collect_stops_on_a_ctrl_c_ignored_in_a_gc_callback_with_130_and_no_dataset(tmp_path, capsys, monkeypatch):
    from ape_jax.pipeline import collect as collect_lib

    armed: list = []
    real_collect = collect_lib.collect

    def collect_(*args, **kwargs):
        armed.append(True)
        gc.collect()   # the SIGINT lands inside the gc callback: ignored, recorded
        assert not armed
        return real_collect(*args, **kwargs)   # stopped at its first batch's progress

    monkeypatch.setattr(collect_lib, "collect", collect_)
    callback = _sigint_in_gc_callback(armed)
    gc.callbacks.append(callback)
    data_dir = tmp_path / "data"
    try:
        code = collect.main(["--env", "toycar", "--obs", "full", "--episodes", "3", "--data-dir", str(data_dir)])
    finally:
        gc.callbacks.remove(callback)
    err = capsys.readouterr().err.strip()
    assert code == 130 and err == ("python -m experiments.collect: interrupted; a dataset is cached only once "
                                   "collected whole"), err
    assert not data_dir.exists() or not any(data_dir.iterdir())


def test_an_interruptible_entry_point_ends_a_ctrl_c_with_one_line_and_130(capsys):
    _cli.Parser(prog="python -m experiments.example")

    @_cli.interruptible("nothing was written")
    def main(argv=None):
        assert signal.getsignal(signal.SIGINT) is _cli._on_sigint
        raise KeyboardInterrupt

    handler = signal.getsignal(signal.SIGINT)
    assert main([]) == 130
    assert capsys.readouterr().err == "\npython -m experiments.example: interrupted; nothing was written\n"
    assert signal.getsignal(signal.SIGINT) is handler


def test_collect_refuses_a_frame_the_task_cannot_render_before_collecting(tmp_path, capsys):
    data_dir = tmp_path / "data"
    err = refused(capsys, lambda: collect.main(["--env", "toytown", "--image-size", "15", "--episodes", "1",
                                                "--data-dir", str(data_dir)]))
    assert err == "python -m experiments.collect: error: --env toytown: image_size must be at least 16x16, got 15x15\n"
    assert not data_dir.exists()
