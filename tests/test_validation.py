"""Bad input at every entry point (but the sweep): one line on stderr, exit status 2, no traceback, nothing touched.

Each case names the entry point, the refused input and the message it must
give; all refusals happen before anything is compiled, so the whole file runs
in seconds. Refusals that the entry points' own test files already cover
(`test_cli`, `test_weights_cli`, `test_report`, `test_experts`, `test_minari`)
are not repeated here.
"""

import json
import pathlib

import numpy as np
import pytest

from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline import minari_io
from ape_jax.pipeline.data import Demonstrations
from experiments import collect, report, train_expert, weights

# Creating a file under /proc fails for every user, root included (a chmod-ed
# directory would not stop root), so it stands in for a read-only location.
READ_ONLY = pathlib.Path("/proc")
needs_read_only = pytest.mark.skipif(not READ_ONLY.is_dir(), reason="needs /proc (Linux)")


def refused(main, argv, capsys) -> str:
    """Runs `main(argv)`, asserts exit status 2 with one line on stderr and no traceback; returns the line."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2, err
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


def tiny_demos() -> Demonstrations:
    """Two episodes (30 and 25 steps) of piecewise-constant 2-d actions and 3-d observations."""
    rng = np.random.default_rng(0)
    lengths = (30, 25)
    n = sum(lengths)
    action = np.repeat(rng.uniform(-1, 1, (11, 2)), 5, axis=0).astype(np.float32)
    return Demonstrations(
        obs=rng.normal(size=(n, 3)).astype(np.float32), action=action, executed=action.copy(),
        episode=np.repeat(np.arange(2, dtype=np.int32), lengths),
        t=np.concatenate([np.arange(k, dtype=np.int32) for k in lengths]),
        done=np.zeros(n, np.float32), reward=np.ones(n, np.float32), sim={"q": np.zeros((n, 2), np.float32)})


@pytest.fixture
def dataset(tmp_path):
    path = tmp_path / "demos.npz"
    data_lib.save(path, tiny_demos(), {"env": "hand"})
    return path


def _raw(edit_arrays=None, edit_meta=None):
    """A dataset file written by hand (no checksum): the arrays and metadata of `tiny_demos`, edited."""
    def make(root):
        arrays = {k: np.asarray(v).copy() for k, v in data_lib._flat(tiny_demos()).items()}
        if edit_arrays:
            edit_arrays(arrays)
        meta = {"obs_shape": [3], "action_size": 2}
        meta = edit_meta(meta) if edit_meta else meta
        path = root / "bad.npz"
        np.savez_compressed(path, **arrays)
        path.with_suffix(".json").write_text(json.dumps(meta))
        return path
    return make


def _set(key, value):
    return lambda a: a.__setitem__(key, value(a[key]) if callable(value) else value)


def _bytes(content: bytes):
    def make(root):
        (root / "bad.npz").write_bytes(content)
        (root / "bad.json").write_text("{}")
        return root / "bad.npz"
    return make


def _minari_metadata(edit):
    def make(root):
        path = minari_io.to_minari(tiny_demos(), {}, "bad-v0", root=root / "minari")
        meta = path / "data" / "metadata.json"
        meta.write_text(json.dumps(edit(json.loads(meta.read_text()))))
        return path
    return make


# -- experiments.weights ----------------------------------------------------------------------

@pytest.mark.parametrize("args, message", [
    (["--w", "inf"], "--w must be a finite number >= 1, got inf"),
    (["--w", "nan"], "--w must be a finite number >= 1, got nan"),
    (["--tau", "inf"], "--tau must be a finite number > 0, got inf"),
    (["--tau", "nan"], "--tau must be a finite number > 0, got nan"),
    (["--thr", "nan"], "--thr must be in (0, 1), got nan"),
    (["--thr", "-0.1"], "--thr must be in (0, 1), got -0.1"),
    (["--ape-steps", "-5"], "--ape-steps must be >= 1, got -5"),
    (["--ape-steps", "many"], "argument --ape-steps: invalid int value: 'many'"),
    (["--bogus"], "unrecognized arguments: --bogus"),
])
def test_weights_refuses_bad_settings(dataset, tmp_path, capsys, args, message):
    err = refused(weights.main, ["--dataset", dataset, "--out", tmp_path / "w.npz", *args], capsys)
    assert message in err and err.startswith("python -m experiments.weights: error:")


@pytest.mark.parametrize("out, message", [
    (lambda root: root / "file" / "w.npz", "file is not a directory"),
    pytest.param(lambda root: READ_ONLY / "w.npz", "cannot write there: /proc is not writable",
                 marks=needs_read_only),
])
def test_weights_refuses_an_out_that_cannot_be_written(dataset, tmp_path, capsys, out, message):
    (tmp_path / "file").write_text("")
    err = refused(weights.main, ["--dataset", dataset, "--out", out(tmp_path)], capsys)
    assert message in err


@pytest.mark.parametrize("make, message", [
    (_raw(_set("reward", lambda r: r.astype(str))), "'reward' must be numbers (bool, int or float), got <U"),
    (_raw(_set("done", lambda d: d.astype(np.complex64))),
     "'done' must be numbers (bool, int or float), got complex64"),
    (_raw(_set("sim/q", lambda q: q.astype(str))), "'sim/q' must be numbers"),
    (_raw(_set("executed", lambda e: e.astype(str))), "'executed' must be a float array shaped like 'action' [55, 2]"),
    (_raw(_set("executed", lambda e: e[:, :1])), "'executed' must be a float array shaped like 'action' [55, 2], "
                                                 "got float32[55, 1]"),
    (_raw(_set("obs", lambda o: o[:, 0]), lambda m: {}), "'obs' must be [N, *obs_shape]"),
    (_raw(_set("obs", lambda o: o.astype(np.int64))), "'obs' must be uint8 (images) or float, got int64"),
    (_raw(lambda a: a.update(action=a["action"][:, :0], executed=a["executed"][:, :0]), lambda m: {}),
     "'action' must be a [N, A] float array with A >= 1, got float32[55, 0]"),
    (_raw(_set("t", lambda t: t.astype(np.float32))), "'t' must be integers, got float32"),
    (_raw(lambda a: a.update(rewards=a.pop("reward"))), "missing keys ['reward']"),
    (_raw(lambda a: a["reward"].__setitem__(7, np.inf)), "'reward' has non-finite values in 1 rows (first: 7)"),
    (_raw(lambda a: a["action"].__setitem__((3, 1), np.nan)), "'action' has non-finite values in 1 rows (first: 3)"),
    (_raw(edit_meta=lambda m: {**m, "obs_shape": 3}), "metadata field 'obs_shape' must be a list of ints, got 3"),
    (_raw(edit_meta=lambda m: {**m, "action_size": "2"}), "metadata field 'action_size' must be an int >= 1, got '2'"),
    (_raw(edit_meta=lambda m: {**m, "sha256": 5}), "metadata field 'sha256' must be a hex string, got 5"),
    (_bytes(b""), "truncated or unreadable (EOFError"),
    (_bytes(b"PK\x03\x04 not a zip"), "truncated or unreadable (BadZipFile"),
    (_minari_metadata(lambda m: [m]), "metadata.json holds a list, not an object"),
    (_minari_metadata(lambda m: {k: v for k, v in m.items() if k != "observation_space"}),
     "metadata.json lacks observation_space"),
])
def test_weights_refuses_a_bad_dataset_naming_it(tmp_path, capsys, make, message):
    path = make(tmp_path)
    err = refused(weights.main, ["--dataset", path, "--out", tmp_path / "w.npz"], capsys)
    assert message in err and str(path.with_suffix("")) in err  # names the file (.npz or its .json)


@pytest.mark.parametrize("args", [
    lambda root: ["--dataset", _raw(_set("reward", lambda r: r.astype(str)))(root)],
    lambda root: ["--dataset", root / "missing.npz"],
    lambda root: ["--dataset", _raw()(root), "--w", "0"],
])
def test_weights_refusals_leave_an_existing_out_untouched(tmp_path, capsys, args):
    out = tmp_path / "w.npz"
    out.write_bytes(b"previous weights")
    refused(weights.main, [*args(tmp_path), "--out", out], capsys)
    assert out.read_bytes() == b"previous weights"
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []  # no temporary left


# -- experiments.collect ----------------------------------------------------------------------

CAR = ["--env", "toycar", "--obs", "full", "--episodes", "1"]


@pytest.mark.parametrize("args, message", [
    (["--noise-std", "nan"], "--noise-std must be a finite number >= 0, got nan"),
    (["--noise-std", "inf"], "--noise-std must be a finite number >= 0, got inf"),
    (["--noise-std", "-0.5"], "--noise-std must be a finite number >= 0, got -0.5"),
    (["--noise-frac", "nan"], "--noise-frac must be in [0, 1], got nan"),
    (["--batch", "0"], "--batch must be >= 1, got 0"),
    (["--episodes", "-3"], "--episodes must be >= 1, got -3"),
    (["--episodes", "ten"], "argument --episodes: invalid int value: 'ten'"),
    (["--obs", "image", "--image-size", "0x5"],
     "--image-size '0x5': an image size is N, HxW or H,W (positive integers)"),
    (["--env", "hopper", "--obs", "rgb"], "--obs 'rgb' is not supported by hopper; valid: full, pos, image"),
    (lambda root: ["--data-dir", root / "file"], "is a file; it must be a directory"),
    (lambda root: ["--data-dir", root / "file" / "cache"], "--data-dir {root}/file/cache: cannot write the dataset "
                                                           "there: {root}/file is not a directory"),
    pytest.param(lambda root: ["--data-dir", READ_ONLY / "cache"], "cannot write the dataset there: /proc is not "
                 "writable", marks=needs_read_only),
    (lambda root: ["--format", "minari", "--out", root / "file" / "m"], "--out {root}/file/m: cannot write there"),
    pytest.param(lambda root: ["--format", "minari", "--out", READ_ONLY / "m"], "/proc is not writable",
                 marks=needs_read_only),
    (lambda root: ["--preview", root / "file" / "p.gif"], "--preview {root}/file/p.gif: cannot write there"),
    (lambda root: ["--preview", root / "dir.gif"], "{root}/dir.gif is a directory"),
])
def test_collect_refuses_bad_input_before_collecting(tmp_path, capsys, args, message):
    (tmp_path / "file").write_text("")
    (tmp_path / "dir.gif").mkdir()
    args = args(tmp_path) if callable(args) else args
    err = refused(collect.main, [*CAR, "--data-dir", tmp_path / "cache", *args], capsys)
    assert message.format(root=tmp_path) in err
    assert not (tmp_path / "cache").exists()  # nothing was collected


def _cached(root):
    """The cache file `collect` would load for CAR, holding a small dataset (nothing collected)."""
    from ape_jax.pipeline import collect as collect_lib

    cfg = collect_lib.data_key("toycar", "full", 1)
    path = data_lib.cache_path(root, cfg)
    data_lib.save(path, tiny_demos(), {"settings": cfg})
    return path


def test_collect_refuses_a_corrupt_cached_dataset_and_leaves_it(tmp_path, capsys):
    path = _cached(tmp_path)
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])
    files = {p: p.read_bytes() for p in tmp_path.iterdir()}
    err = refused(collect.main, [*CAR, "--data-dir", tmp_path], capsys)
    assert f"{path}: contents differ from when it was written (SHA-256 mismatch)" in err
    assert "run again with --force to collect it anew" in err
    assert {p: p.read_bytes() for p in tmp_path.iterdir()} == files


def test_collect_refusals_leave_an_existing_minari_out_untouched(tmp_path, capsys):
    out = tmp_path / "minari"
    (out / "other-v0").mkdir(parents=True)
    (out / "other-v0" / "keep.txt").write_text("someone's dataset")
    refused(collect.main, [*CAR, "--data-dir", tmp_path / "cache", "--format", "minari", "--out", out,
                           "--noise-std", "nan"], capsys)
    assert [p.relative_to(out) for p in out.rglob("*")] == [pathlib.Path("other-v0"), pathlib.Path("other-v0/keep.txt")]
    assert (out / "other-v0" / "keep.txt").read_text() == "someone's dataset"


# -- experiments.train_expert -----------------------------------------------------------------

@pytest.mark.parametrize("args, message", [
    (["--stop-at", "nan"], "--stop-at must be a number (inf: never stop early), got nan"),
    (["--eval-episodes", "0"], "--eval-episodes must be >= 1, got 0"),
    (["--steps", "-1"], "--steps must be >= 1, got -1"),
    (["--seed", "1.5"], "argument --seed: invalid int value: '1.5'"),
    (lambda root: ["--out", root / "file" / "x"], "--out {root}/file/x: cannot write there: {root}/file is not a "
                                                  "directory"),
    (lambda root: ["--out", root / "file"], "--out {root}/file is a file; it must be a directory"),
    (lambda root: ["--workdir", root / "file" / "w"], "--workdir {root}/file/w: cannot write there"),
    pytest.param(lambda root: ["--out", READ_ONLY / "x"], "--out /proc/x: cannot write there: /proc is not writable",
                 marks=needs_read_only),
])
def test_train_expert_refuses_bad_input_before_training(tmp_path, capsys, args, message):
    (tmp_path / "file").write_text("")
    args = args(tmp_path) if callable(args) else args
    defaults = ["--workdir", tmp_path / "work", "--out", tmp_path / "expert"]
    err = refused(train_expert.main, ["--env", "hopper", *defaults, *args], capsys)
    assert message.format(root=tmp_path) in err
    assert not (tmp_path / "work").exists() and not (tmp_path / "expert").exists()


# -- experiments.report -----------------------------------------------------------------------

def results() -> dict:
    run = {"method": "bc-oh", "hparams": {}, "seed": 0, "status": "ok", "error": None,
           "eval": {"episodes": 2, "return_mean": 900.0, "return_std": 5.0, "normalized": 45.0},
           "losses": {s: {"unweighted": 0.1, "changepoint": 0.3, "copycat": 0.05} for s in ("train", "val")}}
    return {"schema": 1, "env": "hopper", "obs": "pos", "preset": "quick",
            "config": {"iterations": 100, "seeds": 1, "eval_episodes": 2, "methods": ["bc-oh"]},
            "expert": {"return_mean": 2000.0, "return_std": 50.0, "random_return_mean": 0.0},
            "runs": [run], "summary": [{"method": "bc-oh", "hparams": {}, "n_seeds": 1, "return_mean": 900.0,
                                        "return_std": 0.0, "normalized_mean": 45.0, "normalized_std": 0.0}],
            "timing": {"total_s": 1.0}, "system": {"jax": "0", "backend": "cpu", "devices": 1, "commit": "x"}}


@pytest.mark.parametrize("edit, message", [
    (lambda r: r.update(summary=5), "field 'summary' must be a list, got 5"),
    (lambda r: r["summary"][0].pop("method"), "summary[0] has no field 'method'"),
    (lambda r: r["summary"][0].update(hparams="tau=1"), "summary[0] field 'hparams' must be an object of numbers"),
    (lambda r: r["summary"][0].update(return_mean="high"), "summary[0] field 'return_mean' must be a number or null"),
    (lambda r: r["summary"][0].update(return_mean=float("nan")), "summary[0] has 1 seeds but return nan ± 0.0; "
                                                                 "expected finite numbers"),
    (lambda r: r["runs"][0].pop("losses"), "runs[0] has no field 'losses'"),
    (lambda r: r["runs"][0]["losses"]["val"].pop("copycat"), "runs[0] losses field 'val' must be an object with "
                                                             "numbers"),
    (lambda r: r["config"].pop("iterations"), "config has no field 'iterations'"),
    (lambda r: r.update(expert=None), "field 'expert' must be an object, got None"),
    (lambda r: r["expert"].update(return_mean="n/a"), "expert field 'return_mean' must be a number or null"),
    (lambda r: r.update(env=3), "field 'env' must be a string, got 3"),
])
def test_report_refuses_results_with_missing_or_mistyped_fields(tmp_path, capsys, edit, message):
    r = results()
    edit(r)
    path = tmp_path / "results.json"
    path.write_text(json.dumps(r))
    err = refused(report.main, [path], capsys)
    assert f"{path}: " in err and message in err


@pytest.mark.parametrize("out, message", [
    (lambda root: root, "{root} is a directory"),
    (lambda root: root / "file" / "B.md", "{root}/file is not a directory"),
    (lambda root: root / "binary.md", "it cannot be read as text"),
    pytest.param(lambda root: READ_ONLY / "B.md", "/proc is not writable", marks=needs_read_only),
])
def test_report_refuses_an_out_that_cannot_be_written(tmp_path, capsys, out, message):
    (tmp_path / "file").write_text("")
    (tmp_path / "binary.md").write_bytes(b"\xff\xfe\x00")
    path = tmp_path / "results.json"
    path.write_text(json.dumps(results()))
    err = refused(report.main, [path, "--out", out(tmp_path)], capsys)
    assert f"--out {out(tmp_path)}: cannot write the report there: {message.format(root=tmp_path)}" in err
    assert (tmp_path / "binary.md").read_bytes() == b"\xff\xfe\x00"


def test_report_refusals_leave_an_existing_out_untouched(tmp_path, capsys):
    bad = results()
    bad["summary"][0].pop("n_seeds")
    path = tmp_path / "results.json"
    path.write_text(json.dumps(bad))
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\nhand-written\n")
    assert "summary[0] has no field 'n_seeds'" in refused(report.main, [path, "--out", out], capsys)
    assert out.read_text() == "# Benchmarks\n\nhand-written\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["BENCHMARKS.md", "results.json"]


# -- experiments.bench_* ------------------------------------------------------------------------

@pytest.mark.parametrize("module, args, message", [
    ("bench_train", lambda root: ["--results", root / "missing.json"], "--results {root}/missing.json does not exist"),
    ("bench_train", lambda root: ["--results", root / "other.json"], "--results {root}/other.json: not a sweep "
                                                                     "results file"),
    ("bench_train", lambda root: ["--write", root / "file" / "B.md"], "--write {root}/file/B.md: cannot write there"),
    ("bench_experts", lambda root: ["--repeats", "0"], "--batch, --repeats must be >= 1"),
    ("bench_envs", lambda root: ["--write", root], "--write {root}: cannot write there: {root} is a directory"),
    ("bench_images", lambda root: ["--encoders", "big"],
     "--encoders: unknown ['big']; valid: small, resnet18, patch, drq, each with +group"),
    ("bench_images", lambda root: ["--encoders", "patch+batch"],
     "--encoders: ['patch+batch']: the small and patch encoders take +group"),
    ("bench_images", lambda root: ["--sizes", "4"], "--sizes must be image sides in [8, 512], got [4]"),
    ("bench_methods", lambda root: ["--repeats", "0"], "--repeats must be >= 1"),
    ("bench_methods", lambda root: ["--methods", "bc-so,bogus"], "--methods: unknown ['bogus']; valid: bc-so"),
    ("bench_methods", lambda root: ["--env", "toycar", "--obs", "pos"], "--obs 'pos' is not supported by toycar"),
])
def test_benchmarks_refuse_bad_input_before_timing(tmp_path, capsys, module, args, message):
    import importlib

    main = importlib.import_module(f"experiments.{module}").main
    (tmp_path / "file").write_text("")
    (tmp_path / "other.json").write_text("{}")
    err = refused(main, args(tmp_path), capsys)
    assert message.format(root=tmp_path) in err
