"""Differences over seeds with percentile bootstrap intervals, and the verdicts read from them.

- `bootstrap_difference`, `bootstrap_mean`: the estimators (numpy, seeded: the same inputs give the same
  interval);
- `verdict`: plain words for an interval;
- `history_difference`, `ours_differences`, `versus_bcoh`, `bootstrap_rows`: BC-OH − BC-SO (does the history
  help?) and Ours − BC-OH over seeds, per group;
- `bootstrap_share`, `history_share`: the share of the gap between BC-SO and BC-full (the full state's ceiling)
  that the history recovers, (BC-OH − BC-SO) / (BC-full − BC-SO).
"""

from __future__ import annotations

from typing import NamedTuple
from collections.abc import Mapping, Sequence

import numpy as np

from experiments.report.analysis.groups import Group, Key, Merged, is_rate, ordered
from experiments.report.analysis.selection import CEILING, best_of, comparisons, headline, method_rows, seed_values


BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED = 10_000, 0


class Interval(NamedTuple):
    """A difference of means `a − b` with its bootstrap confidence interval `[low, high]`."""

    diff: float
    low: float
    high: float
    n_a: int
    n_b: int


def bootstrap_difference(a: Sequence[float], b: Sequence[float], resamples: int = BOOTSTRAP_RESAMPLES,
                         level: float = 0.95, seed: int = BOOTSTRAP_SEED) -> Interval:
    """Percentile bootstrap interval of `mean(a) − mean(b)`, resampling each arm's seeds independently.

    Args:
      a, b: per-seed values of the two arms (e.g. each seed's mean return), `[n_a]` and `[n_b]`, n ≥ 1.
      resamples: bootstrap replicates.
      level: coverage of the interval (0.95: the 2.5th to 97.5th percentile of the replicates).
      seed: the numpy RNG seed; the same inputs always give the same interval.

    Returns:
      `Interval(diff, low, high, n_a, n_b)`, `diff` the observed difference of means.
    """
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.ndim != 1 or b.ndim != 1 or not a.size or not b.size:
        raise ValueError(f"bootstrap_difference needs two non-empty 1-d arms, got shapes {a.shape} and {b.shape}")
    rng = np.random.default_rng(seed)
    low, high = _percentiles(_resampled_means(a, rng, resamples) - _resampled_means(b, rng, resamples), level)
    return Interval(float(a.mean() - b.mean()), float(low), float(high), int(a.size), int(b.size))


def bootstrap_mean(values: Sequence[float], resamples: int = BOOTSTRAP_RESAMPLES, level: float = 0.95,
                   seed: int = BOOTSTRAP_SEED) -> tuple[float, float, float]:
    """`(mean, low, high)`: the mean of per-seed `values` with its percentile bootstrap interval (seeds resampled
    with replacement; the same inputs always give the same interval)."""
    x = np.asarray(values, np.float64)
    if x.ndim != 1 or not x.size:
        raise ValueError(f"bootstrap_mean needs a non-empty 1-d array, got shape {x.shape}")
    low, high = _percentiles(_resampled_means(x, np.random.default_rng(seed), resamples), level)
    return float(x.mean()), float(low), float(high)


def _resampled_means(x: np.ndarray, rng: np.random.Generator, resamples: int) -> np.ndarray:
    return x[rng.integers(0, x.size, size=(resamples, x.size))].mean(1)


def _percentiles(replicates: np.ndarray, level: float) -> tuple[float, float]:
    tail = 100 * (1 - level) / 2
    low, high = np.percentile(replicates, [tail, 100 - tail])
    return float(low), float(high)


def verdict(ci: Interval, a: str = "Ours", b: str = "BC-OH") -> str:
    """Plain words: `a` better / `b` better when the interval excludes 0, else not significant."""
    if min(ci.n_a, ci.n_b) < 2:
        return "no verdict (needs ≥ 2 seeds per arm)"
    if ci.low > 0:
        return f"{a} better"
    if ci.high < 0:
        return f"{b} better"
    return "not significant (CI contains 0)"


class RecipeCell(NamedTuple):
    """A mean over seeds with its 95% bootstrap interval, and the seeds' values: one method under one recipe (% of
    expert), or one configuration at one iteration (`TrainingPoint`, `BudgetPoint`)."""

    mean: float
    low: float
    high: float
    seeds: tuple[float, ...]


def mean_cell(values: Sequence[float]) -> RecipeCell | None:
    """`RecipeCell` of per-seed `values`: their mean with its 95% bootstrap interval; None for no values."""
    return RecipeCell(*bootstrap_mean(values), tuple(values)) if values else None


# -- Ours − BC-OH and BC-OH − BC-SO per group ----------------------------------------------------------------------

def bootstrap_unit(m: Group) -> tuple[str, str, float]:
    """What the bootstrap compares in a group: `(eval key, unit, factor)`: the mean return, or for a task judged by a
    rate (whose reward is not its measure) that rate in % points."""
    return (m.metric, f"{m.metric}, % points", 100.0) if is_rate(m) else ("return_mean", "return", 1.0)


class Difference(NamedTuple):
    """One comparison over seeds in one group: `a − b` with its bootstrap interval (`bootstrap_rows`).

    `kind` is `"history"` (BC-OH − BC-SO: does the history help?) or `"ours"` (a configuration of Ours −
    BC-OH); `label` says what is compared, `a` and `b` name the arms for `verdict`, `unit` the numbers'.
    """

    key: Key
    title: str
    kind: str
    label: str
    a: str
    b: str
    ci: Interval
    unit: str


def _unit_seeds(m: Group, row: dict | None, key: str | None = None, factor: float | None = None) -> list[float]:
    """`seed_values` of summary row `row` in `bootstrap_unit(m)` (or of `eval[key] × factor`), what the bootstrap
    compares."""
    default_key, _, default_factor = bootstrap_unit(m)
    factor = default_factor if factor is None else factor
    return [factor * v for v in seed_values(m, row, key or default_key)]


def history_difference(m: Group, key: str | None = None, factor: float | None = None) -> Interval | None:
    """BC-OH − BC-SO over seeds in group `m` (each the best of its rows), by default in `bootstrap_unit(m)`; None if
    either has no seeds. With `key`/`factor`, of `eval[key] × factor` instead (`"normalized"`, 1: % of expert
    points)."""
    bcoh = _unit_seeds(m, best_of(method_rows(m, "bc-oh")), key, factor)
    bcso = _unit_seeds(m, best_of(method_rows(m, "bc-so")), key, factor)
    return bootstrap_difference(bcoh, bcso) if bcoh and bcso else None


class Share(NamedTuple):
    """`(a − b) / (c − b)` of three arms' means with its bootstrap interval `[low, high]`, and each arm's seeds."""

    share: float
    low: float
    high: float
    n_a: int
    n_b: int
    n_c: int


def bootstrap_share(a: Sequence[float], b: Sequence[float], c: Sequence[float], resamples: int = BOOTSTRAP_RESAMPLES,
                    level: float = 0.95, seed: int = BOOTSTRAP_SEED) -> Share | None:
    """Percentile bootstrap interval of `(mean(a) − mean(b)) / (mean(c) − mean(b))`: how much of the gap from `b`
    to `c` `a` covers (each arm's seeds resampled independently, as `bootstrap_difference` does).

    Args:
      a, b, c: per-seed values of the three arms, `[n_a]`, `[n_b]`, `[n_c]`, n ≥ 1.

    Returns:
      `Share`, or None where `mean(c) = mean(b)` (no gap to share). Replicates whose own gap is 0 are left out;
      where the gap's interval holds 0 the share's is wide (or unbounded), as it should be.
    """
    a, b, c = (np.asarray(x, np.float64) for x in (a, b, c))
    if any(x.ndim != 1 or not x.size for x in (a, b, c)):
        raise ValueError(f"bootstrap_share needs three non-empty 1-d arms, got shapes {a.shape}, {b.shape}, {c.shape}")
    if c.mean() == b.mean():
        return None
    rng = np.random.default_rng(seed)
    ma, mb, mc = (_resampled_means(x, rng, resamples) for x in (a, b, c))
    gap = mc - mb
    low, high = _percentiles((ma - mb)[gap != 0] / gap[gap != 0], level)
    return Share(float((a.mean() - b.mean()) / (c.mean() - b.mean())), low, high, a.size, b.size, c.size)


def history_share(m: Group) -> Share | None:
    """How much of the gap between BC-SO and BC-full (BC on the full state: the ceiling) the history recovers in
    group `m`: `(BC-OH − BC-SO) / (BC-full − BC-SO)` over seeds (each the best of its rows, in `bootstrap_unit(m)`),
    with its 95% bootstrap interval; None where one of the three has no seeds or BC-full equals BC-SO."""
    arms = [_unit_seeds(m, best_of(method_rows(m, method))) for method in ("bc-oh", "bc-so", CEILING)]
    return bootstrap_share(*arms) if all(arms) else None


def ours_differences(m: Group) -> list[tuple[str, dict, Interval]]:
    """Ours − BC-OH over seeds in group `m`, in `bootstrap_unit(m)`: `(label, Ours' summary row, interval)` per
    configuration of `comparisons` that has seeds (none if BC-OH has none)."""
    bcoh = _unit_seeds(m, best_of(method_rows(m, "bc-oh")))
    out = []
    for lab, row in comparisons(m) if bcoh else []:
        ours = _unit_seeds(m, row)
        if ours:
            out.append((lab, row, bootstrap_difference(ours, bcoh)))
    return out


def versus_bcoh(m: Group, extras: Sequence[str] = (), known: Mapping[str, dict] | None = None,
                ceiling: bool = False) -> list[tuple[str, dict | None, Interval | None]]:
    """Every row of the state table of group `m` (`headline`, BC-full's with `ceiling`) but BC-OH, against BC-OH:
    `(label, summary row, row − BC-OH over seeds in `bootstrap_unit(m)`, or None where either arm has no seeds)`."""
    bcoh = _unit_seeds(m, best_of(method_rows(m, "bc-oh")))
    out = []
    for lab, row in headline(m, extras, known, ceiling):
        if lab == "BC-OH":
            continue
        values = _unit_seeds(m, row)
        out.append((lab, row, bootstrap_difference(values, bcoh) if values and bcoh else None))
    return out


def bootstrap_rows(merged: Merged) -> list[Difference]:
    """Per group (task, observation mode, protocol), in report order: BC-OH − BC-SO ("does the history help?"),
    then Ours − BC-OH per configuration of `comparisons`, each with its 95% CI, in `bootstrap_unit`."""
    out = []
    for key, m in ordered(merged):
        unit = bootstrap_unit(m)[1]
        history = history_difference(m)
        if history is not None:
            out.append(Difference(key, m.title, "history", "BC-OH − BC-SO (does the history help?)", "BC-OH",
                                  "BC-SO", history, unit))
        out += [Difference(key, m.title, "ours", f"{lab} − BC-OH", "Ours", "BC-OH", ci, unit)
                for lab, _, ci in ours_differences(m)]
    return out
