"""Training curves on disk (`ape_jax.pipeline.logs`): the CSV read back exactly, the TensorBoard events read back
as window means, directory-safe unique labels, and rewrites that leave nothing stale.

The `tensorboard` package (and its EventAccumulator) is not a dependency, so the event files are read
here with a small TFRecord reader and tensorboardX's own `Event` protobuf.
"""

import csv
import json
import re
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from tensorboardX.proto.event_pb2 import Event
from tensorboardX.record_writer import masked_crc32c

from ape_jax.pipeline.logs import run_label, write_curves
from ape_jax import methods, tasks
from ape_jax.pipeline.sweep import Run, grid_runs

RUNS = [Run("bc-oh", {}, 0), Run("ours-step", {"thr": 0.1, "w": 5.0}, 0), Run("ours-step", {"thr": 0.1, "w": 5.0}, 1)]


def read_csv(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def read_events(run_dir):
    """{tag: (steps [N] int, values [N] float32)} from the single event file in `run_dir`, CRCs checked."""
    (path,) = run_dir.iterdir()
    assert path.name.startswith("events.out.tfevents.")
    data, curves, offset = path.read_bytes(), {}, 0
    while offset < len(data):
        header = data[offset:offset + 8]
        (length,) = struct.unpack("<Q", header)
        (header_crc,) = struct.unpack("<I", data[offset + 8:offset + 12])
        record = data[offset + 12:offset + 12 + length]
        (record_crc,) = struct.unpack("<I", data[offset + 12 + length:offset + 16 + length])
        assert header_crc == masked_crc32c(header) and record_crc == masked_crc32c(record)
        offset += 16 + length
        event = Event.FromString(record)
        for value in event.summary.value:
            curves.setdefault(value.tag, []).append((event.step, value.simple_value))
    return {tag: (np.array([s for s, _ in points]), np.array([v for _, v in points], np.float32))
            for tag, points in curves.items()}


def test_csv_has_one_row_per_run_and_iteration_with_exact_values_and_nonfinite_kept(tmp_path):
    rng = np.random.default_rng(0)
    iterations = 40
    loss = (rng.lognormal(size=(3, iterations)) * 10.0 ** rng.integers(-30, 30, (3, iterations))).astype(np.float32)
    loss[0, 5], loss[1, 7], loss[2, 9] = np.nan, np.inf, -np.inf
    unweighted = rng.normal(size=(3, iterations)).astype(np.float32)
    unweighted[:, -1] = [np.finfo(np.float32).tiny / 8, np.finfo(np.float32).max, -0.0]  # subnormal, max, -0
    write_curves(tmp_path, "grid", RUNS, {"loss": loss, "unweighted_loss": unweighted})

    rows = read_csv(tmp_path / "curves" / "grid.csv")
    assert list(rows[0]) == ["run", "method", "hparams", "seed", "iteration", "loss", "unweighted_loss"]
    assert len(rows) == len(RUNS) * iterations
    for i, run in enumerate(RUNS):
        mine = rows[i * iterations:(i + 1) * iterations]
        assert {(r["run"], r["method"], r["seed"]) for r in mine} == {(run_label(run), run.method, str(run.seed))}
        assert all(json.loads(r["hparams"]) == run.hparams for r in mine)
        assert [int(r["iteration"]) for r in mine] == list(range(1, iterations + 1))
        for name, values in (("loss", loss), ("unweighted_loss", unweighted)):
            read = np.array([float(r[name]) for r in mine], np.float32)
            np.testing.assert_array_equal(read.view(np.uint32), values[i].view(np.uint32))  # bit for bit
    assert rows[5]["loss"] == "nan" and rows[iterations + 7]["loss"] == "inf"
    assert json.loads(rows[iterations]["hparams"]) == {"thr": 0.1, "w": 5.0}


@settings(max_examples=20, deadline=None)
@given(hnp.arrays(np.float32, st.tuples(st.integers(1, 3), st.integers(1, 6)),
                  elements=st.floats(width=32, allow_nan=True, allow_infinity=True)))
def test_csv_round_trips_any_float32(tmp_path_factory, values):
    out = tmp_path_factory.mktemp("curves")
    runs = [Run("bc-oh", {}, seed) for seed in range(values.shape[0])]
    write_curves(out, "p", runs, {"loss": values}, tb_points=2)
    read = np.array([float(r["loss"]) for r in read_csv(out / "curves" / "p.csv")], np.float32)
    nan = np.isnan(values.ravel())
    np.testing.assert_array_equal(np.isnan(read), nan)
    np.testing.assert_array_equal(read[~nan].view(np.uint32), values.ravel()[~nan].view(np.uint32))


def test_tensorboard_holds_the_mean_of_each_window_at_its_last_iteration(tmp_path):
    loss = np.stack([np.arange(1, 11), np.arange(1, 11) * 10]).astype(np.float32)   # [2 runs, 10 iterations]
    adversary = np.ones((2, 10), np.float32)
    adversary[1, 4] = np.nan
    runs = [Run("fca", {"alpha": 0.5}, 0), Run("fca", {"alpha": 0.5}, 1)]
    write_curves(tmp_path, "fca", runs, {"loss": loss, "adversary_loss": adversary}, tb_points=4)

    tb = tmp_path / "tensorboard"
    assert sorted(p.name for p in tb.iterdir()) == ["fca_alpha=0.5_seed0", "fca_alpha=0.5_seed1"]
    # 10 iterations in at most 4 points: windows of 3, i.e. 1-3, 4-6, 7-9 and 10 alone.
    for i, run in enumerate(runs):
        curves = read_events(tb / run_label(run))
        assert set(curves) == {"train/loss", "train/adversary_loss"}
        steps, means = curves["train/loss"]
        np.testing.assert_array_equal(steps, [3, 6, 9, 10])
        np.testing.assert_array_equal(means, np.array([2, 5, 8, 10], np.float32) * 10 ** i)
    steps, means = read_events(tb / "fca_alpha=0.5_seed1")["train/adversary_loss"]
    np.testing.assert_array_equal(steps, [3, 6, 9, 10])
    np.testing.assert_array_equal(means, [1, np.nan, 1, 1])   # the diverged window is written as NaN


def test_tensorboard_writes_every_iteration_when_there_are_few(tmp_path):
    loss = np.array([[0.5, 0.25, 0.125]], np.float32)
    write_curves(tmp_path, "bc-so", [Run("bc-so", {}, 2)], {"loss": loss}, tb_points=3)
    steps, values = read_events(tmp_path / "tensorboard" / "bc-so_seed2")["train/loss"]
    np.testing.assert_array_equal(steps, [1, 2, 3])
    np.testing.assert_array_equal(values, loss[0])


def test_labels_are_readable_unique_and_directory_safe():
    assert run_label(Run("ours-step", {"w": 5.0, "thr": 0.1}, 0)) == "ours-step_thr=0.1_w=5_seed0"
    assert run_label(Run("bc-oh", {}, 2)) == "bc-oh_seed2"
    assert run_label(Run("x", {"lr": 1e-5, "big": 1e20, "name": "a b/c", "on": True}, 3)) == \
        "x_big=1e20_lr=1e-05_name=a-b-c_on=True_seed3"   # 1e+20: the + dropped
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=800)   # every method's grid at its defaults
    runs = grid_runs(methods.names(), 3, ctx)
    labels = [run_label(run) for run in runs]
    assert len(set(labels)) == len(runs) > 30
    assert all(re.fullmatch(r"[A-Za-z0-9._=-]+", label) for label in labels)


def test_a_second_write_replaces_the_first_and_leaves_nothing_stale(tmp_path):
    first = np.full((3, 30), 7.0, np.float32)
    write_curves(tmp_path, "grid", RUNS, {"loss": first, "unweighted_loss": first}, tb_points=5)
    second = np.arange(3 * 8, dtype=np.float32).reshape(3, 8)
    write_curves(tmp_path, "grid", RUNS, {"loss": second}, tb_points=8)   # a resumed sweep: shorter, one metric

    assert [p.name for p in (tmp_path / "curves").iterdir()] == ["grid.csv"]
    rows = read_csv(tmp_path / "curves" / "grid.csv")
    assert len(rows) == 3 * 8 and "unweighted_loss" not in rows[0]
    np.testing.assert_array_equal([float(r["loss"]) for r in rows], second.ravel())
    tb = tmp_path / "tensorboard"
    assert sorted(p.name for p in tb.iterdir()) == sorted(run_label(r) for r in RUNS)   # no staging left
    for i, run in enumerate(RUNS):
        curves = read_events(tb / run_label(run))   # one event file: the first write's is gone
        assert list(curves) == ["train/loss"]
        np.testing.assert_array_equal(curves["train/loss"][1], second[i])


@pytest.mark.parametrize("runs, metrics, tb_points, match", [
    (RUNS, {"loss": np.zeros((2, 5), np.float32)}, 10, "len\\(runs\\)=3"),
    (RUNS, {"loss": np.zeros((3, 5)), "unweighted_loss": np.zeros((3, 6))}, 10, "iterations"),
    (RUNS, {"loss": np.zeros((3, 0))}, 10, "no iterations"),
    (RUNS, {"train loss": np.zeros((3, 5))}, 10, "metric names"),
    (RUNS, {"seed": np.zeros((3, 5))}, 10, "metric names"),
    (RUNS, {}, 10, "no metrics"),
    (RUNS, {"loss": np.zeros((3, 5))}, 0, "tb_points"),
    (RUNS[1:] + RUNS[1:2], {"loss": np.zeros((3, 5))}, 10, "share the labels"),
])
def test_write_curves_refuses_what_it_cannot_write_faithfully(tmp_path, runs, metrics, tb_points, match):
    with pytest.raises(ValueError, match=match):
        write_curves(tmp_path, "grid", runs, metrics, tb_points=tb_points)
    assert not any(tmp_path.iterdir())   # refused before writing anything


def read_all_events(run_dir):
    """{tag: {step: value}} over every event file in `run_dir` (a live run's directory holds two)."""
    out = {}
    for path in sorted(run_dir.iterdir()):
        sub = run_dir / ".one"
        sub.mkdir()
        try:
            (sub / path.name).write_bytes(path.read_bytes())
            for tag, (steps, values) in read_events(sub).items():
                for step, value in zip(steps.tolist(), values.tolist()):
                    assert step not in out.setdefault(tag, {}), f"{tag} logged twice at step {step}"
                    out[tag][step] = value
        finally:
            for f in sub.iterdir():
                f.unlink()
            sub.rmdir()
    return out


@pytest.mark.parametrize("restored", [0, 7])
def test_a_curve_log_writes_while_training_and_ends_as_one_write_at_the_end(tmp_path, restored):
    """`CurveLog`: after every chunk the CSV holds every iteration so far and each run's events every window the
    iterations so far complete (windows of the whole program's width, none twice); closed, both files are
    byte for byte / point for point what `write_curves` writes at the end. `restored`: a resumed program's
    first iterations, given to `start`."""
    from ape_jax.pipeline.logs import CurveLog

    rng = np.random.default_rng(1)
    total, tb_points = 23, 5     # windows of 5 iterations, the last of 3
    loss = rng.normal(size=(3, total)).astype(np.float32)
    aux = rng.normal(size=(3, total)).astype(np.float32)
    live, whole = tmp_path / "live", tmp_path / "whole"
    log = CurveLog(live, "grid", RUNS, total, tb_points=tb_points)
    log.start({"loss": loss[:, :restored], "aux": aux[:, :restored]} if restored else None)
    done = restored
    for n in (4, 6, 1, 12)[: None if not restored else 3]:
        n = min(n, total - done)
        log.append({"loss": loss[:, done:done + n], "aux": aux[:, done:done + n]})
        done += n
        rows = read_csv(live / "curves" / "grid.csv")
        assert sorted((r["run"], int(r["iteration"])) for r in rows) == \
            sorted((run_label(run), i) for run in RUNS for i in range(1, done + 1))
        for i, run in enumerate(RUNS):
            events = read_all_events(live / "tensorboard" / run_label(run))
            ends = [e for e in (5, 10, 15, 20, 23) if e <= done]
            assert sorted(events.get("train/loss", {})) == ends
            for end in ends:   # the window's mean, from its first iteration ((end - 1) // 5 * 5, 0-based)
                window = loss[i, (end - 1) // 5 * 5:end].astype(np.float64)
                assert events["train/loss"][end] == pytest.approx(window.mean(), rel=1e-6)
    if done < total:
        log.append({"loss": loss[:, done:], "aux": aux[:, done:]})
    log.close()
    write_curves(whole, "grid", RUNS, {"loss": loss, "aux": aux}, tb_points=tb_points)
    assert (live / "curves" / "grid.csv").read_bytes() == (whole / "curves" / "grid.csv").read_bytes()
    for run in RUNS:
        a, b = read_events(live / "tensorboard" / run_label(run)), read_events(whole / "tensorboard" / run_label(run))
        assert a.keys() == b.keys()
        for tag in a:
            np.testing.assert_array_equal(a[tag][0], b[tag][0])
            np.testing.assert_array_equal(a[tag][1], b[tag][1])
    assert sorted(p.name for p in (live / "tensorboard").iterdir()) == sorted(run_label(r) for r in RUNS)


def test_a_curve_log_gathers_tiny_chunks_into_at_most_fifty_writes(tmp_path):
    """A CPU image sweep hands over a chunk every 10 iterations: `CurveLog` writes once `iterations / 50` have
    gathered, so a run's directory gets at most ~50 event files while training, and every row still lands."""
    from ape_jax.pipeline.logs import FLUSHES, CurveLog

    total, chunk = 5_000, 10
    loss = np.random.default_rng(2).normal(size=(3, total)).astype(np.float32)
    log = CurveLog(tmp_path, "grid", RUNS, total)
    log.start(None)
    assert log.flush_every == total // FLUSHES == 100
    for start in range(0, total, chunk):
        log.append({"loss": loss[:, start:start + chunk]})
        if start + chunk == 2_000:   # mid-training: all but the last < 100 iterations written, every run alike
            rows = read_csv(tmp_path / "curves" / "grid.csv")
            assert 3 * (2_000 - 100) < len(rows) <= 3 * 2_000 and len(rows) % 3 == 0
    events = list((tmp_path / "tensorboard" / run_label(RUNS[0])).iterdir())
    assert len(events) <= FLUSHES + 1
    log.close()
    assert len(read_csv(tmp_path / "curves" / "grid.csv")) == 3 * total
    assert len(list((tmp_path / "tensorboard" / run_label(RUNS[0])).iterdir())) == 1   # rewritten whole


def test_the_csv_gets_the_mode_any_new_file_gets(tmp_path):
    """Written through a private temporary file (0600), it ends with the umask's mode, like the run folder's others."""
    import os

    old = os.umask(0o022)
    try:
        write_curves(tmp_path, "grid", RUNS, {"loss": np.ones((len(RUNS), 3), np.float32)})
    finally:
        os.umask(old)
    assert (tmp_path / "curves" / "grid.csv").stat().st_mode & 0o777 == 0o644
