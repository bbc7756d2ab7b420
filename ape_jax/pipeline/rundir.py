"""A sweep's output folder (`--out`): every file and folder in it, named in one place.

    out = RunDir("runs/sweep/hopper-pos-quick")
    res = results.load(out.results)
    policies = checkpoint.load_policies(out.params)

| path | what | written by |
|---|---|---|
| `results.json` | every run's record and the summary | `results.save`, last: its presence means the sweep finished |
| `results.csv` | one summary row per configuration | `results.write_csv` |
| `params/` | the trained policies, `<group>/` (`h<H>`, `full-h1`) beside `<group>.json` | `checkpoint.save_policies` |
| `checkpoints/` | a running sweep's state, deleted when it finishes | `checkpoint.SweepCheckpoint` |
| `curves/<program>.csv` | every iteration's training metrics | `logs.write_curves`, `logs.CurveLog` |
| `tensorboard/<run label>/` | the same, downsampled, for TensorBoard | `logs.write_curves`, `logs.CurveLog` |
| `videos/` | GIFs of evaluation episodes | `experiments.evaluate --video` (`watch`) |
| `sweep.lock` | who holds the folder while a sweep runs (pid, host, start) | `checkpoint.OutLock`, deleted at the end |

Nothing here writes: it says where (and `finished` looks).
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from typing import ClassVar


@dataclasses.dataclass(frozen=True)
class RunDir:
    """The paths of one sweep's output folder (see the module docstring).

    Attributes:
      root: the folder (the sweep's `--out`); any path-like, kept as a `pathlib.Path`.
    """

    root: pathlib.Path

    # the names, for a reader that looks for them (e.g. `folder.glob(f"*/{RunDir.RESULTS}")`)
    RESULTS: ClassVar[str] = "results.json"
    CSV: ClassVar[str] = "results.csv"
    PARAMS: ClassVar[str] = "params"
    CHECKPOINTS: ClassVar[str] = "checkpoints"
    CURVES: ClassVar[str] = "curves"
    TENSORBOARD: ClassVar[str] = "tensorboard"
    VIDEOS: ClassVar[str] = "videos"
    LOCK: ClassVar[str] = "sweep.lock"

    def __post_init__(self):
        object.__setattr__(self, "root", pathlib.Path(os.fspath(self.root)))

    @property
    def results(self) -> pathlib.Path:
        return self.root / self.RESULTS

    @property
    def csv(self) -> pathlib.Path:
        return self.root / self.CSV

    @property
    def params(self) -> pathlib.Path:
        return self.root / self.PARAMS

    @property
    def checkpoints(self) -> pathlib.Path:
        return self.root / self.CHECKPOINTS

    @property
    def curves(self) -> pathlib.Path:
        return self.root / self.CURVES

    @property
    def tensorboard(self) -> pathlib.Path:
        return self.root / self.TENSORBOARD

    @property
    def videos(self) -> pathlib.Path:
        return self.root / self.VIDEOS

    @property
    def lock(self) -> pathlib.Path:
        return self.root / self.LOCK

    def curve_csv(self, program: str) -> pathlib.Path:
        """One program's training curves: `curves/<program>.csv`."""
        return self.curves / f"{program}.csv"

    def video(self, method: str, seed: int, episode: int) -> pathlib.Path:
        """Where `experiments.evaluate --video` writes an episode: `videos/<method>-seed<S>-episode<E>.gif`."""
        return self.videos / f"{method}-seed{seed}-episode{episode}.gif"

    @property
    def sweep_outputs(self) -> tuple[pathlib.Path, ...]:
        """What `experiments.sweep` writes (and `--fresh` deletes): the results, the policies, the curves and the
        checkpoints. Videos are the viewer's and stay."""
        return (self.results, self.csv, self.params, self.curves, self.tensorboard, self.checkpoints)

    def finished(self) -> bool:
        """Whether the folder holds a finished sweep: its `results.json` and `params/`."""
        return self.results.is_file() and self.params.is_dir()
