"""Differences over seeds with their intervals (`experiments.stats`, the one engine), and the verdicts read from them.

- `mean_difference`, `mean_estimate`: a difference of means with Welch's t-interval and a mean with Student's
  (`stats.welch_difference`, `stats.mean_interval`);
- `verdict`: plain words for an interval;
- `history_difference`, `ours_differences`, `versus_bcoh`, `difference_rows`: BC-OH − BC-SO (does the history
  help?) and Ours − BC-OH over seeds, per group;
- `history_share`: the share of the gap between BC-SO and BC-full (the full state's ceiling) that the history
  recovers, (BC-OH − BC-SO) / (BC-full − BC-SO), with `stats.gap_share`'s bootstrap interval.
- `driving_comparisons`: the comparisons the paper reads off its driving tables (BC-OH − BC-SO, Ours − BC-SO,
  Ours − BC-OH, Ours − DAgger in success; Ours − BC-OH in collisions per episode), per driving group.
"""

from __future__ import annotations

from typing import NamedTuple
from collections.abc import Mapping, Sequence

from experiments import stats
from experiments.report.analysis.groups import Group, Key, Merged, is_rate, ordered
from experiments.report.analysis.selection import (CEILING, best_of, comparisons, headline, label, method_rows,
                                                   paper_step_row, seed_values)


class Interval(NamedTuple):
    """A difference of means `a − b` with its 95% confidence interval `[low, high]` (Welch's t), and each arm's
    number of seeds."""

    diff: float
    low: float
    high: float
    n_a: int
    n_b: int


def mean_difference(a: Sequence[float], b: Sequence[float], level: float = 0.95) -> Interval:
    """`mean(a) − mean(b)` over per-seed values `[n_a]`, `[n_b]` (n ≥ 1) with Welch's t-interval
    (`stats.welch_difference`)."""
    e = stats.welch_difference(a, b, level)
    return Interval(e.value, e.low, e.high, len(a), len(b))


def mean_estimate(values: Sequence[float], level: float = 0.95) -> tuple[float, float, float]:
    """`(mean, low, high)`: the mean of per-seed `values` with Student's t-interval (`stats.mean_interval`; one
    value: `[x, x]`)."""
    e = stats.mean_interval(values, level)
    return e.value, e.low, e.high


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
    """A mean over seeds with its 95% t-interval, and the seeds' values: one method under one recipe (% of
    expert), or one configuration at one iteration (`TrainingPoint`, `BudgetPoint`)."""

    mean: float
    low: float
    high: float
    seeds: tuple[float, ...]


def mean_cell(values: Sequence[float]) -> RecipeCell | None:
    """`RecipeCell` of per-seed `values`: their mean with its 95% t-interval; None for no values."""
    return RecipeCell(*mean_estimate(values), tuple(values)) if values else None


# -- Ours − BC-OH and BC-OH − BC-SO per group ----------------------------------------------------------------------

def difference_unit(m: Group) -> tuple[str, str, float]:
    """What the differences compare in a group: `(eval key, unit, factor)`: the mean return, or for a task judged by a
    rate (whose reward is not its measure) that rate in % points."""
    return (m.metric, f"{m.metric}, % points", 100.0) if is_rate(m) else ("return_mean", "return", 1.0)


class Difference(NamedTuple):
    """One comparison over seeds in one group: `a − b` with its Welch t-interval (`difference_rows`).

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
    """`seed_values` of summary row `row` in `difference_unit(m)` (or of `eval[key] × factor`), what the differences
    compares."""
    default_key, _, default_factor = difference_unit(m)
    factor = default_factor if factor is None else factor
    return [factor * v for v in seed_values(m, row, key or default_key)]


def history_difference(m: Group, key: str | None = None, factor: float | None = None) -> Interval | None:
    """BC-OH − BC-SO over seeds in group `m` (each the best of its rows), by default in `difference_unit(m)`; None if
    either has no seeds. With `key`/`factor`, of `eval[key] × factor` instead (`"normalized"`, 1: % of expert
    points)."""
    bcoh = _unit_seeds(m, best_of(method_rows(m, "bc-oh")), key, factor)
    bcso = _unit_seeds(m, best_of(method_rows(m, "bc-so")), key, factor)
    return mean_difference(bcoh, bcso) if bcoh and bcso else None


class Share(NamedTuple):
    """`(a − b) / (c − b)` of three arms' means with its percentile bootstrap interval `[low, high]`, and each arm's
    number of seeds."""

    share: float
    low: float
    high: float
    n_a: int
    n_b: int
    n_c: int


def gap_share(a: Sequence[float], b: Sequence[float], c: Sequence[float]) -> Share | None:
    """`(mean(a) − mean(b)) / (mean(c) − mean(b))` over per-seed values (n ≥ 1 each): how much of the gap from `b` to
    `c` `a` covers, with `stats.gap_share`'s percentile bootstrap interval; None where `mean(c) = mean(b)`."""
    e = stats.gap_share(a, b, c)
    return None if e is None else Share(e.value, e.low, e.high, len(a), len(b), len(c))


def history_share(m: Group) -> Share | None:
    """How much of the gap between BC-SO and BC-full (BC on the full state: the ceiling) the history recovers in
    group `m`: `(BC-OH − BC-SO) / (BC-full − BC-SO)` over seeds (each the best of its rows, in `difference_unit(m)`),
    with its 95% percentile bootstrap interval; None where one of the three has no seeds or BC-full equals BC-SO."""
    arms = [_unit_seeds(m, best_of(method_rows(m, method))) for method in ("bc-oh", "bc-so", CEILING)]
    return gap_share(*arms) if all(arms) else None


def ours_differences(m: Group) -> list[tuple[str, dict, Interval]]:
    """Ours − BC-OH over seeds in group `m`, in `difference_unit(m)`: `(label, Ours' summary row, interval)` per
    configuration of `comparisons` that has seeds (none if BC-OH has none)."""
    bcoh = _unit_seeds(m, best_of(method_rows(m, "bc-oh")))
    out = []
    for lab, row in comparisons(m) if bcoh else []:
        ours = _unit_seeds(m, row)
        if ours:
            out.append((lab, row, mean_difference(ours, bcoh)))
    return out


def versus_bcoh(m: Group, extras: Sequence[str] = (), known: Mapping[str, dict] | None = None,
                ceiling: bool = False) -> list[tuple[str, dict | None, Interval | None]]:
    """Every row of the state table of group `m` (`headline`, BC-full's with `ceiling`) but BC-OH, against BC-OH:
    `(label, summary row, row − BC-OH over seeds in `difference_unit(m)`, or None where either arm has no seeds)`."""
    bcoh = _unit_seeds(m, best_of(method_rows(m, "bc-oh")))
    out = []
    for lab, row in headline(m, extras, known, ceiling):
        if lab == "BC-OH":
            continue
        values = _unit_seeds(m, row)
        out.append((lab, row, mean_difference(values, bcoh) if values and bcoh else None))
    return out


def difference_rows(merged: Merged) -> list[Difference]:
    """Per group (task, observation mode, protocol), in report order: BC-OH − BC-SO ("does the history help?"),
    then Ours − BC-OH per configuration of `comparisons`, each with its 95% CI, in `difference_unit`."""
    out = []
    for key, m in ordered(merged):
        unit = difference_unit(m)[1]
        history = history_difference(m)
        if history is not None:
            out.append(Difference(key, m.title, "history", "BC-OH − BC-SO (does the history help?)", "BC-OH",
                                  "BC-SO", history, unit))
        out += [Difference(key, m.title, "ours", f"{lab} − BC-OH", "Ours", "BC-OH", ci, unit)
                for lab, _, ci in ours_differences(m)]
    return out


# -- the paper's comparisons in a driving group (the supplement's Tables 1 and 2) ------------------------------------

# What the paper reads off its driving tables: `(a, b, metric)`, `a − b` over seeds, the metric None for the task's
# main one (ToyTown's success); `ours-step` is Ours at the paper's step setting, every other method its best row.
DRIVING_COMPARISONS = (("bc-oh", "bc-so", None), ("ours-step", "bc-so", None), ("ours-step", "bc-oh", None),
                       ("ours-step", "dagger", None), ("ours-step", "bc-oh", "collisions"))


class Comparison(NamedTuple):
    """One of the paper's comparisons in one group (`driving_comparisons`): `a − b` in `eval[metric]` over seeds with
    its Welch t-interval, in `unit` (`"points"`: a rate's % points; `"per episode"`: a per-episode mean as it is)."""

    a: str
    b: str
    metric: str
    unit: str
    ci: Interval


def _driving_arm(m: Group, method: str) -> dict | None:
    return paper_step_row(m) if method == "ours-step" else best_of(method_rows(m, method))


def driving_comparisons(m: Group) -> list[Comparison]:
    """The comparisons of `DRIVING_COMPARISONS` that group `m` ran both arms of, in that order: each difference of
    means over seeds with its 95% Welch t-interval (`mean_difference`); a rate (the main metric) in % points. Arms are
    named `"Ours"` (the paper's step setting) or by their label (`label`, without "(online)")."""
    out = []
    for a, b, metric in DRIVING_COMPARISONS:
        metric = metric or m.metric
        scale = 100.0 if metric == m.metric and is_rate(m) else 1.0
        arms = [[scale * v for v in seed_values(m, _driving_arm(m, x), metric)] for x in (a, b)]
        if all(arms):
            names = ["Ours" if x == "ours-step" else label(m.methods, x, online=False) for x in (a, b)]
            out.append(Comparison(*names, metric, "points" if scale == 100.0 else "per episode",
                                  mean_difference(*arms)))
    return out
