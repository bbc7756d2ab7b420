"""The methods that came after the paper (`LATER`: RAP, PALR, MINE, ChannelDropout, PTP, ActionChunks, Priming)
ranked with the paper's, per family of cells.

A *cell* is a merged group (one task, protocol, expert and budget) in which at least one of `LATER` ran, trained at
its preset's budget (a run trained longer, such as the paper's 300k, reads in its own section: in a family it would
leave out every method it did not run). Cells fall into two families, by their setting (never by their results):

- where copying is expected (`is_copycat_cell`): an expert of FCA's kind (`regime.is_regime`: FCA's imported expert or
  raw labels) or the previous action in view (`protocol.prev_action`), the settings where BC-OH is expected to copy;
- the default tasks: every other cell (the shipped experts under the paper's protocol).

Per family, `ranking` gives each method of `RANKED` that ran in every cell of the family: the interquartile mean of
% of expert over all its seeds with a stratified bootstrap interval (`stats.iqm_across_tasks`), the probability
that one of its runs beats one of BC-OH's (`stats.probability_of_improvement`), and per cell its difference from
BC-OH in points with Welch's t-interval (`differences.mean_difference`) and its controlled copycat
counts. A method with several configurations in a cell is represented by its best one there (by mean % of expert,
as `experiments.compare` and the report's best rows choose: optimistic for methods with many configurations).

`onpolicy_check` is the trap's test beside the ranking (issue 59): in every cell where copying is expected and DAgger
or HistoryDropout ran, each against BC-OH. On-policy imitation is the field's known answer to copying, so where
DAgger clears BC-OH the cell is sound (copying is what holds BC-OH back, and an offline remedy that does not clear
it fails there); where DAgger does not, something other than copying holds the cell down, to be found before
its ranking is read.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from experiments import stats
from experiments.report.analysis.differences import Interval, mean_difference
from experiments.report.analysis.diagnostics import PolicyDiagnostics, policy_diagnostics
from experiments.report.analysis.groups import Group, Merged, ordered
from experiments.report.analysis.regime import cell_title, is_regime
from experiments.report.analysis.selection import LATER, best_of, is_finite, method_rows, ok_runs

RANKED = ("bc-so", "bc-oh", "bc-full", "ours-step", "ours-softmax", "fca", *LATER)  # the ranking's methods, in order
REFERENCE = "bc-oh"  # what every method is measured against
RESAMPLES = 2000  # bootstrap resamples of the across-cell estimates (`stats`' default)
ONPOLICY = ("dagger", "history-dropout")   # the on-policy check's methods (`onpolicy_check`), the oracle first


class CellResult(NamedTuple):
    """One method in one cell: its chosen configuration's hyperparameters, its per-seed % of expert, its difference
    from BC-OH (None for BC-OH itself) and its copycat diagnostics over seeds."""

    cell: str
    hparams: dict
    seeds: tuple[float, ...]
    versus: Interval | None
    diagnostics: PolicyDiagnostics


class Ranked(NamedTuple):
    """One method's place in a family: its cells (`CellResult`, in the family's order), the IQM of % of expert over
    every cell's seeds with its interval, and P(a run beats a BC-OH run) with its interval (None for BC-OH)."""

    method: str
    cells: tuple[CellResult, ...]
    iqm: stats.Estimate
    improvement: stats.Estimate | None


class Family(NamedTuple):
    """A family of cells (`copycat` or `default`), its cells' titles in order, and its methods, best IQM first;
    `partial`: the methods of `RANKED` that ran in some of its cells but not all, with the titles of those they ran
    in (left out of the ranking: an IQM over fewer cells would not compare)."""

    name: str
    cells: tuple[str, ...]
    ranked: tuple[Ranked, ...]
    partial: tuple[tuple[str, tuple[str, ...]], ...] = ()


def is_copycat_cell(m: Group) -> bool:
    """Whether group `m` is set where BC-OH is expected to copy: an expert of FCA's kind or the previous action in
    view."""
    return is_regime(m) or bool(m.protocol.get("prev_action"))


def ranking_cells(merged: Merged) -> dict[str, list[Group]]:
    """The groups at their preset's budget in which one of `LATER` ran with seeds, in report order, by family:
    `{"copycat": [...], "default": [...]}` (a family without cells is left out)."""
    out: dict[str, list[Group]] = {}
    for _, m in ordered(merged):
        if (m.budget is None and any(method_rows(m, name) for name in LATER)
                and m.expert.get("return_mean") is not None):
            out.setdefault("copycat" if is_copycat_cell(m) else "default", []).append(m)
    return out


def _seeds(m: Group, row: dict) -> tuple[float, ...]:
    runs = sorted(ok_runs(m, row["method"], row["hparams"]), key=lambda r: r.get("seed", 0))
    return tuple(float(r["eval"]["normalized"]) for r in runs if is_finite(r["eval"].get("normalized")))


def _cell_result(m: Group, title: str, method: str, reference: tuple[float, ...]) -> CellResult | None:
    row = best_of([r for r in method_rows(m, method) if r.get("normalized_mean") is not None])
    seeds = () if row is None else _seeds(m, row)
    if not seeds:
        return None
    versus = mean_difference(seeds, reference) if method != REFERENCE and reference else None
    return CellResult(title, dict(row["hparams"]), seeds, versus,
                      policy_diagnostics(ok_runs(m, method, row["hparams"])))


def _titles(cells: Sequence[Group]) -> tuple[str, ...]:
    titles = tuple(cell_title(m) for m in cells)
    if len(set(titles)) < len(titles):   # two cells of one task and setting (other budgets, protocols): full titles
        titles = tuple(m.title for m in cells)
    return titles


def family(name: str, cells: Sequence[Group], reps: int = RESAMPLES) -> Family:
    """Family `name`'s ranking over `cells`: every method of `RANKED` that ran in every cell (BC-OH first where it
    did not), best IQM first; those that ran in some cells only are named in `Family.partial`. Cells without BC-OH
    give no differences; a family without BC-OH in every cell gives no probability of improvement."""
    titles = _titles(cells)
    reference = {t: (r.seeds if (r := _cell_result(m, t, REFERENCE, ())) else ()) for t, m in zip(titles, cells)}
    ranked, partial = [], []
    for method in RANKED:
        results = [_cell_result(m, t, method, reference[t]) for t, m in zip(titles, cells)]
        if any(r is None for r in results):
            if ran := tuple(r.cell for r in results if r is not None):
                partial.append((method, ran))
            continue
        scores = {r.cell: np.asarray(r.seeds) for r in results}
        improvement = (stats.probability_of_improvement(scores, {t: np.asarray(s) for t, s in reference.items()},
                                                         reps=reps)
                       if method != REFERENCE and all(reference.values()) else None)
        ranked.append(Ranked(method, tuple(results), stats.iqm_across_tasks(scores, reps=reps), improvement))
    ranked.sort(key=lambda r: -r.iqm.value)
    return Family(name, titles, tuple(ranked), tuple(partial))


def ranking(merged: Merged, reps: int = RESAMPLES) -> list[Family]:
    """Both families' rankings (`family`), where copying is expected first; empty where no file holds one of `LATER`."""
    cells = ranking_cells(merged)
    return [family(name, cells[name], reps) for name in ("copycat", "default") if name in cells]


class Check(NamedTuple):
    """The on-policy check in one cell where copying is expected: BC-OH − BC-SO (what the history adds; None without
    BC-SO), BC-OH's result, each of `ONPOLICY` that ran against it (`{method: CellResult}`), and whether the cell is
    sound: DAgger's interval against BC-OH above 0 (None where DAgger did not run)."""

    cell: str
    history: Interval | None
    bcoh: CellResult
    methods: dict[str, CellResult]
    sound: bool | None


def onpolicy_check(merged: Merged) -> list[Check]:
    """Per cell where copying is expected (`is_copycat_cell`) at its preset's budget, with BC-OH and one of
    `ONPOLICY`: the check (`Check`), in report order."""
    cells = [m for _, m in ordered(merged)
             if m.budget is None and is_copycat_cell(m) and m.expert.get("return_mean") is not None
             and method_rows(m, REFERENCE) and any(method_rows(m, name) for name in ONPOLICY)]
    out = []
    for title, m in zip(_titles(cells), cells):
        bcoh = _cell_result(m, title, REFERENCE, ())
        if bcoh is None:
            continue
        bcso = _cell_result(m, title, "bc-so", ())
        found = {name: r for name in ONPOLICY if (r := _cell_result(m, title, name, bcoh.seeds))}
        oracle = found.get(ONPOLICY[0])
        out.append(Check(title, None if bcso is None else mean_difference(bcoh.seeds, bcso.seeds), bcoh, found,
                         None if oracle is None else bool(oracle.versus.low > 0)))
    return out
