"""`experiments.weights`: APE and weights of a dataset in either format; refusals with exit code 2."""

import json

import numpy as np
import pytest

from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline import minari_io
from ape_jax.pipeline.data import Demonstrations
from experiments import weights

STEPS = 300  # enough for ψ to learn "repeat the last action", so changepoints stand out


def keyframe_demos(lengths=(60, 45, 70, 50), seed=0) -> Demonstrations:
    """Piecewise-constant expert actions: the steps where they change are the keyframes."""
    rng = np.random.default_rng(seed)
    parts = []
    for k in lengths:
        change = np.r_[True, rng.uniform(size=k - 1) < 0.1]
        parts.append(rng.uniform(-1, 1, (change.sum(), 2))[np.cumsum(change) - 1])
    action = np.concatenate(parts).astype(np.float32)
    n = len(action)
    return Demonstrations(
        obs=rng.normal(size=(n, 3)).astype(np.float32), action=action, executed=action,
        episode=np.repeat(np.arange(len(lengths), dtype=np.int32), lengths),
        t=np.concatenate([np.arange(k, dtype=np.int32) for k in lengths]),
        done=np.zeros(n, np.float32), reward=np.ones(n, np.float32))


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    demos = keyframe_demos()
    data_lib.save(root / "demos.npz", demos, {"env": "hand"})
    minari_io.to_minari(demos, {"env": "hand"}, "demos-v0", root=root / "minari")
    return demos, root / "demos.npz", root / "minari" / "demos-v0"


@pytest.fixture(scope="module")
def outputs(datasets, tmp_path_factory):
    _, npz, mds = datasets
    out = tmp_path_factory.mktemp("out")
    files = {}
    for name, dataset in (("npz", npz), ("minari", mds)):
        files[name] = out / f"{name}.npz"
        argv = ["--dataset", str(dataset), "--out", str(files[name]), "--ape-steps", str(STEPS),
                "--thr", "0.1", "--w", "5", "--tau", "0.5", "--seed", "3"]
        assert weights.main(argv) == 0
    return {name: dict(np.load(path)) for name, path in files.items()}


@pytest.mark.parametrize("fmt", ["npz", "minari"])
def test_weights_file_has_every_array_in_dataset_order(datasets, outputs, fmt):
    demos, npz, mds = datasets
    f = outputs[fmt]
    n = len(demos)
    assert sorted(f) == ["ape", "ape_raw", "episode", "meta", "softmax_weights", "step_weights", "t"]
    for k in ("ape", "ape_raw", "step_weights", "softmax_weights"):
        assert f[k].shape == (n,) and f[k].dtype == np.float32 and np.all(np.isfinite(f[k]))
    np.testing.assert_array_equal(f["episode"], demos.episode)
    np.testing.assert_array_equal(f["t"], demos.t)
    meta = json.loads(str(f["meta"]))
    assert meta["format"] == fmt and meta["dataset"] == str(npz if fmt == "npz" else mds)
    assert meta["num_transitions"] == n and meta["num_episodes"] == 4 and meta["ape_steps"] == STEPS
    np.testing.assert_allclose(f["ape"] * meta["ape_scale"], f["ape_raw"], rtol=1e-6)
    assert f["ape"].mean() == pytest.approx(1.0, rel=1e-5)
    # step: exactly ⌊thr·N⌋ samples get w, the ones with the largest APE
    assert set(np.unique(f["step_weights"])) == {1.0, 5.0}
    up = f["step_weights"] == 5.0
    assert up.sum() == int(0.1 * n)
    assert f["ape"][up].min() >= f["ape"][~up].max()
    # softmax over the whole dataset: N · softmax(ape / tau), mean 1, ordered like APE
    np.testing.assert_allclose(f["softmax_weights"].mean(), 1.0, rtol=1e-5)
    e = np.exp(f["ape"].astype(np.float64) / 0.5 - f["ape"].max() / 0.5)
    np.testing.assert_allclose(f["softmax_weights"], n * e / e.sum(), rtol=1e-4, atol=1e-6)


def test_high_ape_marks_the_changepoints(datasets, outputs):
    demos = datasets[0]
    change = np.r_[False, np.any(demos.action[1:] != demos.action[:-1], axis=1)] & (demos.t > 0)
    ape = outputs["npz"]["ape"]
    assert ape[change].mean() > 10 * ape[~change].mean()


def test_both_formats_give_the_same_ape(outputs):
    np.testing.assert_allclose(outputs["npz"]["ape_raw"], outputs["minari"]["ape_raw"], rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(outputs["npz"]["step_weights"], outputs["minari"]["step_weights"])


def test_summary_is_printed_and_an_existing_output_is_replaced(datasets, tmp_path, capsys):
    out = tmp_path / "w.npz"
    out.write_bytes(b"old")
    argv = ["--dataset", str(datasets[1]), "--out", str(out), "--ape-steps", "20"]
    assert weights.main(argv) == 0
    text = capsys.readouterr().out
    assert "225 samples in 4 episodes" in text and "22 samples (10%) upweighted to 5" in text
    assert f"weights: {out}" in text
    assert np.load(out)["ape"].shape == (225,) and sorted(p.name for p in tmp_path.iterdir()) == ["w.npz"]


def test_the_directory_of_out_is_made_if_missing(datasets, tmp_path):
    out = tmp_path / "new" / "dir" / "w.npz"
    assert weights.main(["--dataset", str(datasets[1]), "--out", str(out), "--ape-steps", "20"]) == 0
    assert np.load(out)["ape"].shape == (225,)


def _one_step_episodes(root):
    demos = keyframe_demos(lengths=(1,) * 30)
    data_lib.save(root / "short.npz", demos)
    return root / "short.npz"


def _tiny(root):
    demos = keyframe_demos(lengths=(5, 4))
    data_lib.save(root / "tiny.npz", demos)
    return root / "tiny.npz"


def _truncated(root):
    data_lib.save(root / "t.npz", keyframe_demos())
    raw = (root / "t.npz").read_bytes()
    (root / "t.npz").write_bytes(raw[: len(raw) // 2])
    return root / "t.npz"


def _file_parent(root):
    (root / "file").write_text("")
    return root / "file" / "w.npz"


def _directory(root):
    (root / "d.npz").mkdir()
    return root / "d.npz"


@pytest.mark.parametrize("args, message", [
    (["--thr", "0"], "--thr must be in (0, 1), got 0.0"),
    (["--thr", "1.5"], "--thr must be in (0, 1)"),
    (["--w", "0.5"], "--w must be a finite number >= 1, got 0.5"),
    (["--tau", "0"], "--tau must be a finite number > 0"),
    (["--tau", "-1"], "--tau must be a finite number > 0"),
    (["--ape-steps", "0"], "--ape-steps must be >= 1"),
    (["--format", "parquet"], "invalid choice: 'parquet'"),
])
def test_refuses_bad_settings_with_exit_code_2(datasets, tmp_path, args, message, capsys):
    argv = ["--dataset", str(datasets[1]), "--out", str(tmp_path / "w.npz"), *args]
    with pytest.raises(SystemExit) as exc:
        weights.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("dataset, out, message", [
    (lambda root: root / "missing.npz", None, "no such dataset file"),
    (lambda root: root / "missing", None, "no such Minari dataset"),
    (lambda root: root, None, "not a Minari dataset"),
    (_truncated, None, "SHA-256 mismatch"),
    (_one_step_episodes, None, "every episode has fewer than 2 steps"),
    (_tiny, None, "too small: with 9 samples, ⌊thr·N⌋ = 0 would be upweighted"),
    (None, _file_parent, "file is not a directory"),
    (None, _directory, "is a directory"),
    (None, lambda root: root / "w.txt", "--out must name a .npz file"),
])
def test_refuses_bad_datasets_and_outputs_with_one_line_and_exit_code_2(datasets, tmp_path, dataset, out,
                                                                       message, capsys):
    path = dataset(tmp_path) if dataset else datasets[1]
    target = out(tmp_path) if out else tmp_path / "w.npz"
    with pytest.raises(SystemExit) as exc:
        weights.main(["--dataset", str(path), "--out", str(target), "--ape-steps", "10"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert [line for line in err.splitlines() if "error:" in line] == [err.splitlines()[-1]]
    assert not target.is_file()
