"""What the host gives a sweep (`Hooks`): progress bars, messages and a sink for training curves."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

from ape_jax.pipeline.spec import Run


class _NoBar:
    def __init__(self, *a, **k):
        self.n = 0

    def update(self, n=1):
        self.n += n

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@dataclasses.dataclass(frozen=True)
class Hooks:
    """What the host gives a sweep: how to show progress and where to send messages and curves.

    Attributes:
      bar: `bar(desc=..., total=..., unit=...)`, a context manager with
        `update(n)` (e.g. `tqdm.tqdm`); one per phase.
      log: receives one-line progress messages.
      curves: `curves(program, runs, iterations)` before each program trains: a sink for its per-iteration
        metrics (e.g. `logs.CurveLog`), told `start(restored)` with the curves a resumed program restored
        (`[len(runs), n]` per metric, or None), `append(metrics)` after every chunk, and `close()` at the end.
    """

    bar: Callable[..., Any] = _NoBar
    log: Callable[[str], None] = print
    curves: Callable[[str, Sequence[Run], int], Any] | None = None
