"""The numbers of a rate-judged task's plain reading (ToyCar): did BC-SO learn the task, the differences between
methods on the rate, and whether BC-OH's inertia appears; `sections.task_metrics` puts them in words."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from experiments.report.analysis.differences import Interval, mean_difference, mean_estimate
from experiments.report.analysis.groups import Group, is_rate
from experiments.report.analysis.selection import task_metric_rows

LEARNED = 90.0  # % of episodes: BC-SO has learned the task when its rate's t-interval is above this


class Estimate(NamedTuple):
    """A mean over seeds (in %) with its 95% t-interval, and the number of seeds."""

    mean: float
    low: float
    high: float
    seeds: int


class RateReading(NamedTuple):
    """What a rate-judged task's reading says, in numbers (`rate_reading`).

    `bcso`: BC-SO's rate (None where it did not run); `episodes`: evaluation episodes per seed where every run
    had the same number (else None); `differences`: `(a, b, Interval)` for BC-OH − BC-SO and Ours (step) − BC-OH,
    in points of the rate, where both ran; `inertia`: BC-OH's share of episodes stuck (standing still while
    free to go), None where not recorded, and `others` the other methods' means (`{"bc-so": %, "ours-step": %}`).
    """

    metric: str
    bcso: Estimate | None
    episodes: int | None
    differences: list[tuple[str, str, Interval]]
    inertia: Estimate | None
    others: dict[str, float]

    @property
    def learned(self) -> bool | None:
        """Whether BC-SO's rate is above `LEARNED` with its whole interval (None: BC-SO did not run)."""
        return None if self.bcso is None else self.bcso.low >= LEARNED


def per_seed(runs: list[dict], key: str, scale: float = 1.0) -> np.ndarray:
    """`eval[key]` of each run that records it, × `scale`."""
    return np.array([r["eval"][key] for r in runs if key in r["eval"]], float) * scale


def rate_reading(m: Group) -> RateReading | None:
    """The reading's numbers for group `m` (None for a task judged by a return)."""
    if not is_rate(m):
        return None
    rows = {method: runs for _, method, runs in task_metric_rows(m)}
    metric = m.metric
    episodes = sorted({int(r["eval"]["episodes"]) for runs in rows.values() for r in runs if "episodes" in r["eval"]})
    bcso = None
    if "bc-so" in rows:
        bcso = Estimate(*mean_estimate(per_seed(rows["bc-so"], metric, 100.0)), len(rows["bc-so"]))
    differences = [(a, b, mean_difference(per_seed(rows[a], metric, 100.0), per_seed(rows[b], metric, 100.0)))
                   for a, b in (("bc-oh", "bc-so"), ("ours-step", "bc-oh")) if a in rows and b in rows]
    stuck = {method: per_seed(runs, "stuck", 100.0) for method, runs in rows.items()}
    inertia, others = None, {}
    if "bc-oh" in stuck and len(stuck["bc-oh"]):
        inertia = Estimate(*mean_estimate(stuck["bc-oh"]), len(stuck["bc-oh"]))
        others = {k: float(stuck[k].mean()) for k in ("bc-so", "ours-step") if k in stuck and len(stuck[k])}
    return RateReading(metric, bcso, episodes[0] if len(episodes) == 1 else None, differences, inertia, others)
