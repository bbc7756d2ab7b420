"""Where copycat appears: the history's benefit per frame skip, training-set size, recipe and budget.

- `copycat_map`: per task, BC-SO, BC-OH and Ours per frame skip of the mujoco-state family (and per training-set size at
  frame skip 1), with the history's benefit at each;
- `extended_map`: every mujoco-state-family state group as map points, along the recipe, split and budget axes too, with
  BC-OH's copycat diagnostics.
"""

from __future__ import annotations

import math
from typing import NamedTuple
from collections.abc import Sequence

import numpy as np

from experiments.report.analysis.differences import Interval, Share, mean_difference, gap_share
from experiments.report.analysis.diagnostics import PolicyDiagnostics, policy_diagnostics, run_at
from experiments.report.analysis.groups import (STATE, STATE_TRAIN, MUJOCO, Group, Key, Merged, ReportError,
                                                expert_words, group_title, in_state_family, ordered, other_history)
from experiments.report.analysis.selection import CEILING, best_of, is_finite, method_rows, ok_runs, seed_values
from experiments.report.paper import PAPER_STEP, PAPER_STEP_LABEL


# -- the copycat map: the history's benefit per frame skip ---------------------------------------------------------

# The map's methods, (label, method, hparams: None for the best of its rows).
MAP_METHODS = (("BC-SO", "bc-so", None), ("BC-OH", "bc-oh", None), (PAPER_STEP_LABEL, "ours-step", PAPER_STEP))


class MapCell(NamedTuple):
    """One method at one frame skip: % of expert, mean and std over seeds, the seeds, and each seed's value."""

    mean: float
    std: float
    n: int
    seeds: tuple[float, ...]


class MapRow(NamedTuple):
    """One frame skip of the copycat map.

    `cells` are aligned with `MAP_METHODS` (None: not run there); `history` is
    BC-OH − BC-SO in points of % of expert (means from the summary) and
    `history_ci` its Welch t-interval over seeds; `ceiling` is BC-OH's gap to
    the expert, 100 − BC-OH's % of expert. Each is None where its methods did not run.
    """

    frame_skip: int
    protocol: str
    cells: tuple[MapCell | None, ...]
    history: float | None
    history_ci: Interval | None
    ceiling: float | None
    train_transitions: int | None = None


class CopycatMap(NamedTuple):
    """One task's copycat map: `rows`, one per frame skip of the mujoco-state family at mujoco-state's training-set
    size, in increasing order; `data_rows`, one per training-set size at frame skip 1 (mujoco-state's own size included)
    where the files hold other sizes (`mujoco-state-train5k`, `mujoco-state-train80k`), in increasing order, else
    empty."""

    env: str
    obs: str
    title: str
    rows: list[MapRow]
    data_rows: list[MapRow] = []

    def at(self, frame_skip: int) -> MapRow | None:
        return next((r for r in self.rows if r.frame_skip == frame_skip), None)


def _map_cell(m: Group, method: str, hparams: dict | None) -> MapCell | None:
    row = _map_row_of(m, method, hparams)
    if row is None or row.get("normalized_mean") is None:
        return None
    seeds = tuple(seed_values(m, row, "normalized"))
    std = row.get("normalized_std")
    return MapCell(float(row["normalized_mean"]), math.nan if std is None else float(std), int(row["n_seeds"]), seeds)


def copycat_map(merged: Merged) -> list[CopycatMap]:
    """Where copycat appears: per task with mujoco-state-family results at ≥ 2 frame skips, BC-SO, BC-OH and Ours (step
    THR 10% W 5) in % of expert per frame skip, with the history's benefit (BC-OH − BC-SO) and BC-OH's gap to the
    expert.

    The mujoco-state family is one protocol at several frame skips (the same simulated horizon and training-set size),
    so its rows differ only in how often the policy acts: copycat, a policy that repeats its last action
    because its history predicts it, should grow with the frame rate. A group that holds more methods
    or seeds than the map needs (the fca file's full grid) gives only the rows of those three methods.

    Raises:
      ReportError: two protocols of the mujoco-state family at one frame skip for one task.
    """
    by_task: dict[tuple[str, str], dict[tuple[int, int], dict]] = {}
    for key, m in ordered(merged):
        skip, train = m.protocol.get("frame_skip"), m.protocol.get("train_transitions") or STATE_TRAIN
        if (not in_state_family(key.protocol) or m.protocol.get("variant_of") or skip is None
                or key.budget is not None):  # the map of the first recipe; the extended map has the variants
            continue
        cells = by_task.setdefault((key.env, key.obs), {})
        if (skip, train) in cells:
            raise ReportError(f"{key.env} ({key.obs}): protocols {cells[skip, train].protocol['name']} and "
                              f"{key.protocol} both ran at frame skip {skip} with {train:,} training transitions; "
                              "pass the files of one of them")
        cells[skip, train] = m
    out = []
    for (env, obs), cells in by_task.items():
        rows = [_map_row(cells[k], *k) for k in sorted(cells) if k[1] == STATE_TRAIN]
        data = [_map_row(cells[k], *k) for k in sorted(cells, key=lambda k: k[1]) if k[0] == 1]
        data = data if any(r.train_transitions != STATE_TRAIN for r in data) else []
        if len(rows) < 2 and not data:
            continue
        title = group_title(Key(env, obs, STATE), {"name": STATE}, with_protocol=False)
        out.append(CopycatMap(env, obs, title, rows, data))
    return out


def _map_row(m: Group, skip: int, train: int) -> MapRow:
    cells = tuple(_map_cell(m, method, hp) for _, method, hp in MAP_METHODS)
    bcso, bcoh = cells[0], cells[1]
    history = None if bcso is None or bcoh is None else bcoh.mean - bcso.mean
    ci = (mean_difference(bcoh.seeds, bcso.seeds)
          if bcso is not None and bcoh is not None and bcso.seeds and bcoh.seeds else None)
    return MapRow(skip, m.protocol["name"], cells, history, ci, None if bcoh is None else 100.0 - bcoh.mean,
                  train)


def _map_row_of(m: Group, method: str, hparams: dict | None) -> dict | None:
    rows = method_rows(m, method)
    return best_of(rows) if hparams is None else next((r for r in rows if r["hparams"] == hparams), None)


# -- the copycat map, extended: recipe and budget axes, diagnostics as well as returns -----------------------------

class MapPoint(NamedTuple):
    """One cell of the extended copycat map (`extended_map`): one task under one setting (recipe, split), frame skip
    and training-set size, for runs of `run` iterations evaluated at `iteration`.

    `cells` align with `MAP_METHODS` (None: not run); `history` is BC-OH − BC-SO over seeds in points of % of expert
    (None where either did not run); `diagnostics` are BC-OH's there (None where BC-OH did not run)."""

    env: str
    recipe: str
    split: str
    frame_skip: int
    train_transitions: int
    run: int
    iteration: int
    cells: tuple[MapCell | None, ...]
    history: Interval | None
    diagnostics: PolicyDiagnostics | None
    observations: int | None = None  # the policies' history where it is not the protocol's (`other_history`)
    expert: str | None = None        # the expert and labels where not the task's own, clipped (`expert_words`)
    prev_action: bool = False        # the previous action in the observation (`Protocol.prev_action`)
    ceiling: MapCell | None = None   # BC-full (the full state) in % of expert, where it ran
    share: Share | None = None       # (BC-OH − BC-SO) / (BC-full − BC-SO) over seeds, where all three ran

    @property
    def variations(self) -> str:
        """What the cell changes beyond the recipe and split: `", history 7"` where the history is not the
        protocol's, `", expert ppo"` for another expert, `", previous action in view"` (`protocol.prev_action`)."""
        return ("" if self.observations is None else f", history {self.observations}") + (
            "" if self.expert is None else f", expert {self.expert}") + (
            ", previous action in view" if self.prev_action else "")

    @property
    def setting(self) -> str:
        """`"recipe bn-mlp, split by rows"` with its `variations`: what the recipe axis varies."""
        return f"recipe {self.recipe}, split by {self.split}" + self.variations


def _seed_cell(values: Sequence[float]) -> MapCell | None:
    if not values:
        return None
    x = np.asarray(values, np.float64)
    return MapCell(float(x.mean()), float(x.std(ddof=1)) if x.size > 1 else math.nan, int(x.size), tuple(values))


def extended_map(merged: Merged) -> list[MapPoint]:
    """Every state group of the mujoco-state family (the paper's protocol at each frame skip and training-set size,
    under every recipe, split and budget) as map points: one per iteration its runs were evaluated at (`Budget.eval_at`,
    then the end), with BC-SO, BC-OH and Ours (step THR 10% W 5) in % of expert, BC-OH − BC-SO with its 95%
    Welch t-interval over seeds, and BC-OH's copycat diagnostics; where BC-full ran, its % of expert and the
    history's share of the gap between BC-SO and it. In task, setting (recipe mlp before bn-mlp,
    whole episodes before rows), frame skip, size, run length and iteration order."""
    out = []
    for key, m in ordered(merged):
        p = m.protocol
        base = p.get("variant_of") or key.protocol
        if key.obs != "pos" or key.env not in MUJOCO or not in_state_family(base) or p.get("frame_skip") is None:
            continue
        end = int(m.sources[0].config["iterations"])
        chosen = [_map_row_of(m, method, hp) for _, method, hp in (*MAP_METHODS, ("", CEILING, None))]
        runs = [sorted(ok_runs(m, r["method"], r["hparams"]), key=lambda r: r.get("seed", 0)) if r else []
                for r in chosen]
        points = sorted({a["iteration"] for rs in runs for r in rs for a in r.get("at") or ()} | {end})
        for iteration in points:
            at = [[a for r in rs if (a := run_at(r, iteration, end))] for rs in runs]
            *cells, ceiling = (_seed_cell([a["eval"]["normalized"] for a in xs
                                           if is_finite(a["eval"].get("normalized"))]) for xs in at)
            bcso, bcoh = cells[0], cells[1]
            history = mean_difference(bcoh.seeds, bcso.seeds) if bcso and bcoh else None
            share = gap_share(bcoh.seeds, bcso.seeds, ceiling.seeds) if bcso and bcoh and ceiling else None
            out.append(MapPoint(key.env, p.get("recipe") or "mlp", p.get("split") or "episodes", int(p["frame_skip"]),
                                int(p.get("train_transitions") or STATE_TRAIN), end, iteration, tuple(cells), history,
                                policy_diagnostics(at[1]) if at[1] else None, other_history(p), expert_words(p),
                                bool(p.get("prev_action")), ceiling, share))
    rank = {"mlp": 0, "bn-mlp": 1}
    return sorted(out, key=lambda q: (MUJOCO.index(q.env), rank.get(q.recipe, 2), q.recipe, q.split != "episodes",
                                      q.observations or 0, q.expert or "", q.prev_action, q.frame_skip,
                                      q.train_transitions, q.run, q.iteration))
