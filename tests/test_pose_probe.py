"""`experiments.pose_probe`: what an image encoder reads from the frames (issue 26, item 1)."""

import json

import numpy as np
import pytest

from ape_jax.pipeline.data import Demonstrations
from experiments import pose_probe


def _demos(n=50, seed=0):
    rng = np.random.default_rng(seed)
    return Demonstrations(obs=np.zeros((n, 4, 4, 3), np.uint8), action=rng.normal(size=(n, 3)).astype(np.float32),
                          executed=np.zeros((n, 3), np.float32), episode=np.repeat([0, 1], n // 2).astype(np.int32),
                          t=np.tile(np.arange(n // 2), 2).astype(np.int32), done=np.zeros(n, np.float32),
                          reward=np.zeros(n, np.float32),
                          sim={"qpos": rng.normal(size=(n, 6)), "qvel": rng.normal(size=(n, 6))})


def test_the_targets_sit_side_by_side_with_the_roots_x_left_out():
    d = _demos()
    where, y = pose_probe.targets_of(d, ("velocity", "pose", "action"))
    assert y.shape == (50, 6 + 5 + 3) and y.dtype == np.float32
    np.testing.assert_allclose(y[:, where["velocity"]], d.sim["qvel"], rtol=1e-6)
    np.testing.assert_allclose(y[:, where["pose"]], d.sim["qpos"][:, 1:], rtol=1e-6)
    np.testing.assert_allclose(y[:, where["action"]], d.action)


def test_one_minus_r2_is_0_for_the_truth_and_1_for_the_mean_and_the_bc_loss_is_summed_over_dimensions():
    where, y = pose_probe.targets_of(_demos(), ("pose", "action"))
    var = {k: y[:, c].var(0) for k, c in where.items()}
    exact = pose_probe.scores(y, y, where, var)
    assert exact["pose"]["one_minus_r2"] == 0 and exact["action"]["bc_loss"] == 0
    mean = pose_probe.scores(np.broadcast_to(y.mean(0), y.shape), y, where, var)
    assert mean["pose"]["one_minus_r2"] == pytest.approx(1.0, rel=1e-5)
    off = y.copy()
    off[:, where["action"]] += 0.5   # every action dimension off by 0.5: 3 × 0.25 summed
    assert pose_probe.scores(off, y, where, var)["action"]["bc_loss"] == pytest.approx(0.75, rel=1e-5)


@pytest.mark.parametrize("argv, message", [
    (["--targets", "pose,speed"], "--targets 'pose,speed': a comma list of distinct"),
    (["--targets", "pose,pose"], "a comma list of distinct"),
    (["--env", "toycar"], "one of the tasks with an expert and a pose (hopper"),
    (["--iterations", "100", "--points", "10,50"], "--points must end at --iterations (100)"),
    (["--train-episodes", "10,5"], "increasing integers >= 1"),
    (["--history", "0"], "--history must be >= 1"),
    (["--noise", "0.1"], "--noise 0.1: a number >= 0, with --obs pos only"),
    (["--obs", "pos", "--noise", "-1"], "--noise -1: a number >= 0"),
])
def test_bad_input_is_refused_in_one_line(argv, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        pose_probe.parse([*argv, "--out", str(tmp_path / "p.json")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and message in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_probe_of_tiny_hopper_frames_fits_its_training_rows_and_writes_every_point(tmp_path, capsys):
    out = tmp_path / "probe.json"
    argv = ["--image-size", "16x16", "--encoder", "patch", "--iterations", "300", "--points", "20,300", "--seeds",
            "1", "--targets", "pose,action", "--set", "protocol.episodes=3", "--set", "protocol.horizon=20",
            "--set", "recipe.lr=1e-3", "--set", "recipe.batch_size=8", "--out", str(out),
            "--data-dir", str(tmp_path / "data")]
    assert pose_probe.main(argv) == 0
    r = json.loads(out.read_text())
    assert [a["iteration"] for a in r["runs"][0]["at"]] == [20, 300] and r["command"][-len(argv):] == argv
    first, last = r["runs"][0]["at"]
    assert last["train"]["pose"]["one_minus_r2"] < min(0.5, first["train"]["pose"]["one_minus_r2"])
    assert np.isfinite(last["val"]["action"]["bc_loss"]) and r["system"]["commit"]
    assert "| 2 | 300 |" in capsys.readouterr().out
