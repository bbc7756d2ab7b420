"""Per-iteration training curves of one program, as CSV and as TensorBoard event files.

A program (`ape_jax.pipeline.training`) trains a group of runs together and returns, per
metric, a `[len(runs), iterations]` float32 array. `write_curves` writes it twice:

    write_curves(out, "grid", runs, {"loss": loss, "unweighted_loss": unweighted})
    # out/curves/grid.csv                       every iteration of every run
    # out/tensorboard/<run label>/events.out.tfevents.*   at most 1000 points per curve

**CSV** (`out/curves/<program>.csv`), long format, one row per run and
iteration, runs in the order given and iterations ascending; a header row, then

    run,method,hparams,seed,iteration,<metric>,...
    ours-step_thr=0.1_w=5_seed0,ours-step,"{""thr"":0.1,""w"":5.0}",0,1,0.532917857,0.498013943

- `run`: the run's label (`run_label`), also its TensorBoard directory;
- `hparams`: the hyperparameters as compact JSON with sorted keys (quoted as CSV requires);
- `iteration`: 1 for the first training step, up to `iterations`;
- one column per metric, in the dict's order, as `%.9g`: enough digits that
  reading the text back as float32 gives the stored value exactly. Non-finite
  values are written `nan`, `inf`, `-inf`, which `float()` and
  `pandas.read_csv` read back as such.

The file is written under a temporary name in the same directory and renamed
into place, so a reader sees the old file or the whole new one.

**TensorBoard** (`out/tensorboard/<label>/`, one directory per run so
TensorBoard overlays them), written with `tensorboardX`: one scalar per metric,
tagged `train/<metric>`. Writing every iteration would cost ~42 µs per scalar
(a minute for one program), so each curve is downsampled to at most
`tb_points` points: the iterations are cut into consecutive windows of
`ceil(iterations / tb_points)` (the last may be shorter), and each window's mean
(taken in float64, stored as float32) is logged at the window's last iteration
as the step. With `iterations <= tb_points` every iteration is logged as it is.
A window holding a non-finite value is logged anyway, as its NaN or ±inf mean,
so where a run diverged stays visible; the CSV has the exact iterations.

Each run's directory is written to a hidden temporary directory beside it and
renamed into place, replacing the directory of an earlier write with the same
label (a resumed sweep) whole, so no stale event files are left behind.

**While a program trains** (`CurveLog`, what `experiments.sweep` passes as
`Hooks.curves`), both are written as it goes, so `tensorboard --logdir
OUT/tensorboard` shows a sweep while it trains: `start` writes the curves a
resumed program restored from its checkpoint (or just the CSV's header), each
`append` adds a chunk's rows to the CSV (in chunk order: within a chunk, runs in
order, iterations ascending; chunks shorter than 1/50 of the program are gathered
first, so a program is written at most 50 times) and its finished windows to each run's event file
(the window width is the whole program's, so a window is logged once, when its
last iteration is in); `close` then rewrites both whole with `write_curves`,
so a finished program's files are exactly what one write at the end gives.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import pathlib
import re
import shutil
import tempfile
from typing import Any
from collections.abc import Sequence

import numpy as np

from ape_jax.pipeline.rundir import RunDir

_UNSAFE = re.compile(r"[^A-Za-z0-9._=-]")
_METRIC_NAME = re.compile(r"[A-Za-z0-9_.-]+")
_FIXED_COLUMNS = ("run", "method", "hparams", "seed", "iteration")
_ROWS_PER_CHUNK = 8192  # bounds the size of one formatted block (the paper preset has 300k iterations)
FLUSHES = 50  # `CurveLog` writes at most this many times per program (plus the first write and the last)


def run_label(run: Any) -> str:
    """A run's name, safe as a directory name: `"<method>[_k=v...]_seed<seed>"`.

    Hyperparameters come in sorted key order; whole floats lose their `.0`
    (`w=5`), other floats keep their shortest exact form (`thr=0.1`,
    `lr=1e-05`). Any character outside `[A-Za-z0-9._=-]` becomes `-` (a `+`
    is dropped), so two different runs can in principle share a label;
    `write_curves` refuses that.

    Args:
      run: an `ape_jax.pipeline.spec.Run` (anything with `method`, `hparams`, `seed`).

    Returns:
      e.g. `"ours-step_thr=0.1_w=5_seed0"`, `"bc-oh_seed2"`.
    """
    parts = [str(run.method)] + [f"{k}={_label_value(v)}" for k, v in sorted(run.hparams.items())]
    parts.append(f"seed{run.seed}")
    return _UNSAFE.sub("-", "_".join(parts).replace("+", ""))


def write_curves(out_dir: pathlib.Path, program: str, runs: Sequence[Any], metrics: dict[str, np.ndarray],
                 tb_points: int = 1000) -> None:
    """Writes one program's training curves: `curves/<program>.csv` and `tensorboard/<label>/` per run.

    Formats, file names and the TensorBoard downsampling are in the module docstring.

    Args:
      out_dir: the sweep's output directory; `curves/` and `tensorboard/` are created in it.
      program: the program's name (`"grid"`, `"bc-so"`, ...), the CSV's file name.
      runs: the program's runs, `ape_jax.pipeline.spec.Run`, in the order of the metrics' rows.
      metrics: name -> `[len(runs), iterations] float32`, one value per training iteration;
        may hold NaN/inf. Names must match `[A-Za-z0-9_.-]+`.
      tb_points: the most points written per TensorBoard curve (>= 1).

    Raises:
      ValueError: no metrics, shapes that disagree with each other or with `runs`, no
        iterations, a bad metric or program name, two runs with one label, `tb_points < 1`.
    """
    labels = _check(program, runs, metrics, tb_points)
    out = RunDir(out_dir)
    _write_csv(out.curve_csv(program), runs, labels, metrics)
    tb_root = out.tensorboard
    tb_root.mkdir(parents=True, exist_ok=True)
    for i, label in enumerate(labels):
        _write_tensorboard(tb_root, label, {name: values[i] for name, values in metrics.items()}, tb_points)


class CurveLog:
    """One program's training curves, written while it trains (the module docstring says how).

    `CurveLog(out_dir, program, runs, iterations)` is what `Hooks.curves(program, runs, iterations)` returns in
    `experiments.sweep`; the sweep calls `start` once, `append` after every chunk and `close` at the program's end.

    Args:
      out_dir, program, runs, tb_points: as `write_curves`'s.
      iterations: the program's whole length (every round's), which fixes the TensorBoard windows.
    """

    def __init__(self, out_dir: pathlib.Path, program: str, runs: Sequence[Any], iterations: int,
                 tb_points: int = 1000):
        if iterations < 1:
            raise ValueError(f"a program of {iterations} iterations has no curves")
        self._out, self.program, self.runs = RunDir(out_dir), program, list(runs)
        self.iterations, self.tb_points = iterations, tb_points
        # at most FLUSHES writes per program: a CPU image sweep hands over a chunk every 10 iterations
        self.flush_every = max(1, math.ceil(iterations / FLUSHES))
        self._chunks: list[dict[str, np.ndarray]] = []
        self._written = 0   # the iterations on disk
        self._labels: list[str] | None = None

    @property
    def done(self) -> int:
        """The iterations written so far."""
        return sum(next(iter(c.values())).shape[1] for c in self._chunks)

    def start(self, restored: dict[str, np.ndarray] | None = None) -> None:
        """Opens the log: the curves of the iterations a resumed program restored (`[len(runs), n]` per metric), or
        None for a fresh start (the CSV is written when the first chunk's metrics name its columns)."""
        if restored is not None and next(iter(restored.values())).shape[1]:
            self._open({k: np.asarray(v) for k, v in restored.items()})

    def append(self, metrics: dict[str, np.ndarray]) -> None:
        """Adds the next chunk's metrics (`[len(runs), n]` per metric); written once `flush_every` iterations
        have gathered since the last write (every chunk of a state sweep)."""
        metrics = {k: np.asarray(v) for k, v in metrics.items()}
        if self._labels is None:
            self._open(metrics)
            return
        if list(metrics) != list(self._chunks[0]):
            raise ValueError(f"a chunk's metrics {list(metrics)} are not the program's {list(self._chunks[0])}")
        self._chunks.append(metrics)
        if self.done - self._written >= self.flush_every:
            self._flush()

    def _flush(self) -> None:
        """Appends the iterations not yet on disk: their CSV rows, and the TensorBoard windows they complete."""
        pending = _concat_chunks(self._chunks)
        pending = {k: v[:, self._written:] for k, v in pending.items()}
        with open(self._out.curve_csv(self.program), "a", encoding="utf-8", newline="") as f:
            _write_rows(f, self.runs, self._labels, pending, self._written + 1)
        self._log_windows(self._written)
        self._written = self.done

    def close(self) -> None:
        """Rewrites both files whole (`write_curves`), as one write at the end would."""
        if self._chunks:
            metrics = _concat_chunks(self._chunks)
            write_curves(self._out.root, self.program, self.runs, metrics, self.tb_points)

    def _open(self, metrics: dict[str, np.ndarray]) -> None:
        """The first curves: the CSV and every run's event file written whole (what later writes append to)."""
        self._labels = _check(self.program, self.runs, metrics, self.tb_points)
        self._chunks = [metrics]
        self._written = self.done
        _write_csv(self._out.curve_csv(self.program), self.runs, self._labels, metrics)
        tb_root = self._out.tensorboard
        tb_root.mkdir(parents=True, exist_ok=True)
        for i, label in enumerate(self._labels):
            _write_tensorboard(tb_root, label, {name: v[i] for name, v in metrics.items()}, self.tb_points,
                               self.iterations)

    def _log_windows(self, before: int) -> None:
        """Logs the windows that end after iteration `before` and that the curves so far complete: one more event
        file per run, named after the chunk's first iteration, closed at once (TensorBoard reads them all)."""
        from tensorboardX import SummaryWriter

        metrics = _concat_chunks(self._chunks)
        for i, label in enumerate(self._labels):
            points = []
            for name, values in metrics.items():
                steps, means = _window_means(values[i], self.tb_points, self.iterations)
                points += [(f"train/{name}", mean, step) for step, mean in zip(steps.tolist(), means.tolist())
                           if step > before]
            if points:
                writer = SummaryWriter(logdir=str(self._out.tensorboard / label), flush_secs=3600,
                                       filename_suffix=f".{before + 1}")
                try:
                    for tag, mean, step in points:
                        writer.add_scalar(tag, mean, step)
                finally:
                    writer.close()


def _concat_chunks(chunks: Sequence[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Per-chunk metrics `[R, n]` joined along the iteration axis."""
    return {k: np.concatenate([c[k] for c in chunks], axis=1) for k in chunks[0]}


def _label_value(v: Any) -> str:
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (float, np.floating)):
        v = float(v)
        return str(int(v)) if v.is_integer() and abs(v) < 1e15 else repr(v)
    return str(v)


def _check(program: str, runs: Sequence[Any], metrics: dict[str, np.ndarray], tb_points: int) -> list[str]:
    if not metrics:
        raise ValueError("no metrics to write")
    if _UNSAFE.search(program) or program in ("", ".", ".."):
        raise ValueError(f"program name {program!r} is not a safe file name (use [A-Za-z0-9._=-])")
    shapes = {name: np.shape(values) for name, values in metrics.items()}
    (shape, *others) = set(shapes.values())
    if others or len(shape) != 2 or shape[0] != len(runs):
        raise ValueError(f"metrics must all be [len(runs)={len(runs)}, iterations]; got {shapes}")
    if shape[1] == 0:
        raise ValueError(f"metrics hold no iterations: {shapes}")
    bad = [name for name in metrics if not _METRIC_NAME.fullmatch(name) or name in _FIXED_COLUMNS]
    if bad:
        raise ValueError(f"metric names {bad} must match [A-Za-z0-9_.-]+ and not be one of {_FIXED_COLUMNS}")
    if tb_points < 1:
        raise ValueError(f"tb_points must be >= 1, got {tb_points}")
    labels = [run_label(run) for run in runs]
    duplicates = sorted({label for label in labels if labels.count(label) > 1})
    if duplicates:
        raise ValueError(f"runs share the labels {duplicates}; each run of a program needs its own")
    return labels


def _json_default(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    raise TypeError(f"hyperparameter {v!r} of type {type(v).__name__} is not JSON serialisable")


def _csv_fields(fields: list[Any]) -> str:
    """One CSV line (no line end), quoted as the csv module does."""
    buf = io.StringIO()
    csv.writer(buf, lineterminator="").writerow(fields)
    return buf.getvalue()


def _write_rows(f, runs: Sequence[Any], labels: list[str], metrics: dict[str, np.ndarray], first: int = 1) -> None:
    """The CSV rows of `metrics` (`[len(runs), n]`), iterations counted from `first`, runs in order."""
    n_iterations = next(iter(metrics.values())).shape[1]
    iteration = np.arange(first, first + n_iterations, dtype=np.float64)
    for i, (run, label) in enumerate(zip(runs, labels)):
        hparams = json.dumps(run.hparams, sort_keys=True, separators=(",", ":"), default=_json_default)
        prefix = _csv_fields([label, run.method, hparams, int(run.seed)]).replace("%", "%%")
        row = prefix + ",%d" + ",%.9g" * len(metrics) + "\n"
        # [iterations, 1 + metrics] float64 holds every float32 and iteration count exactly;
        # one `%` over a whole chunk of rows formats in C rather than row by row in Python.
        block = np.column_stack([iteration] + [np.asarray(v[i], np.float64) for v in metrics.values()])
        for start in range(0, n_iterations, _ROWS_PER_CHUNK):
            chunk = block[start:start + _ROWS_PER_CHUNK]
            f.write((row * len(chunk)) % tuple(chunk.ravel().tolist()))


def _umask() -> int:
    """The process's umask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _write_csv(path: pathlib.Path, runs: Sequence[Any], labels: list[str], metrics: dict[str, np.ndarray] | None,
               names: Sequence[str] | None = None) -> None:
    """The whole CSV, atomically: the header (`names`: the metrics', default `metrics`'s), then `metrics`'s rows."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with open(fd, "w", encoding="utf-8", newline="") as f:
            f.write(_csv_fields([*_FIXED_COLUMNS, *(names if names is not None else metrics)]) + "\n")
            if metrics is not None:
                _write_rows(f, runs, labels, metrics)
        os.chmod(tmp, 0o666 & ~_umask())   # mkstemp makes it 0600: give it the mode any new file gets here
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def _window_means(values: np.ndarray, tb_points: int, total: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`[T]` -> (steps `[P] int`, means `[P] float64`) of the windows of a `total`-iteration curve (default `T`)
    that `values`, its first T iterations, complete: windows of `ceil(total / tb_points)` iterations, the last
    one shorter, so P <= tb_points."""
    n = len(values)
    total = n if total is None else total
    width = math.ceil(total / tb_points)
    starts = np.arange(0, total, width)
    ends = np.minimum(starts + width, total)
    starts, ends = starts[ends <= n], ends[ends <= n]
    if not len(starts):
        return ends, np.zeros(0)
    means = np.add.reduceat(np.asarray(values[:ends[-1]], np.float64), starts) / (ends - starts)
    return ends, means  # a window's last iteration, counting from 1, is its end index


def _write_tensorboard(tb_root: pathlib.Path, label: str, curves: dict[str, np.ndarray], tb_points: int,
                       total: int | None = None) -> None:
    # Imported here: tensorboardX imports torch when it is installed (~2 s), which
    # importers of this module that never write curves should not pay.
    from tensorboardX import SummaryWriter

    staging = pathlib.Path(tempfile.mkdtemp(prefix=f".{label}.", suffix=".tmp", dir=tb_root))
    try:
        writer = SummaryWriter(logdir=str(staging), flush_secs=3600)
        try:
            for name, values in curves.items():
                steps, means = _window_means(values, tb_points, total)
                for step, mean in zip(steps.tolist(), means.tolist()):
                    writer.add_scalar(f"train/{name}", mean, step)
        finally:
            writer.close()
        _swap_into_place(staging, tb_root / label)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def _swap_into_place(staging: pathlib.Path, target: pathlib.Path) -> None:
    """Renames `staging` to `target`, replacing an existing `target` directory whole."""
    if not target.exists():
        os.replace(staging, target)
        return
    # A directory cannot be renamed over a non-empty one: move the old one aside first.
    aside = pathlib.Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
    os.replace(target, aside / target.name)
    try:
        os.replace(staging, target)
    except BaseException:
        os.replace(aside / target.name, target)
        raise
    finally:
        shutil.rmtree(aside, ignore_errors=True)
