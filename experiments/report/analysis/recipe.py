"""The paper's recipe and budget: mlp against bn-mlp under one protocol, and the 300k runs beside Table 5.

- `recipe_groups`, `recipe_rows`, `alpha_rows`: per task, every method under each recipe of one protocol, and
  every FCA setting (the α sensitivity);
- `paper_budget_groups`, `budget_rows`, `budget_differences`: the paper's protocol under the bn-mlp recipe for the
  `paper` preset's iterations, each method at every iteration it was evaluated at, beside the supplement's
  Table 5.
"""

from __future__ import annotations

from typing import NamedTuple
from collections.abc import Sequence

import numpy as np

from ape_jax import tasks
from experiments.report.analysis.differences import (Interval, RecipeCell, mean_difference, mean_estimate,
                                                   mean_cell)
from experiments.report.analysis.diagnostics import PolicyDiagnostics, Spread, policy_diagnostics, run_at, spread
from experiments.report.analysis.groups import STATE, MUJOCO, Group, Merged, ordered, other_setting, trained_its_preset
from experiments.report.analysis.selection import CEILING, CEILING_LABEL, is_finite, method_rows, ok_runs, seed_values
from experiments.report.paper import PAPER_STEP, PAPER_STEP_LABEL, PAPER_TABLE5, PAPER_TAU


# -- the paper's recipe: mlp against bn-mlp under one protocol --------------------------------------------------------

# The recipe table's methods, (label, method, hparams: None for the task's default FCA setting).
RECIPE_METHODS = (("BC-SO", "bc-so", {}), ("BC-OH", "bc-oh", {}), (PAPER_STEP_LABEL, "ours-step", PAPER_STEP),
                  ("FCA (TCA)", "fca", None), ("FCA (TCA + IB)", "fca-ib", None), (CEILING_LABEL, CEILING, {}))


class RecipeRow(NamedTuple):
    """One task and method: a cell per recipe (None: not run), and bn-mlp − mlp with its interval (None: not both)."""

    env: str
    label: str
    cells: dict[str, RecipeCell | None]
    difference: Interval | None


def _recipe_row(m: Group, method: str, hparams: dict | None) -> dict | None:
    rows = method_rows(m, method)
    if hparams is None:  # FCA: the task's own α (the FCA code's); the first setting otherwise (and for PALR)
        alpha = tasks.get(m.env).fca_alpha
        rows = [r for r in rows if r["hparams"].get("alpha") == alpha] or rows[:1]
    else:
        rows = [r for r in rows if r["hparams"] == hparams]
    return rows[0] if rows else None


def recipe_groups(merged: Merged) -> dict[tuple[str, str, str], dict[str, Group]]:
    """`{(env, obs, "PROTOCOL, split by SPLIT"): {recipe: group}}` for the groups of `variant_name`s that ran at
    their preset's budget; only settings with more than one recipe."""
    out: dict = {}
    for key, m in ordered(merged):
        p = m.protocol
        if p.get("variant_of") and key.budget is None and not other_setting(p):
            out.setdefault((key.env, key.obs, f"{p['variant_of']}, split by {p.get('split')}"), {})[p["recipe"]] = m
    return {k: v for k, v in out.items() if len(v) > 1}


def recipe_rows(recipes: dict[str, Group], order: Sequence[str] = ("mlp", "bn-mlp")) -> list[RecipeRow]:
    """Per method of `RECIPE_METHODS` that ran under some recipe: its % of expert per recipe (with its t-interval) and
    bn-mlp − mlp (difference of means over seeds with Welch's t-interval, in points of % of expert)."""
    names = [r for r in order if r in recipes] + [r for r in recipes if r not in order]
    out = []
    for lab, method, hparams in RECIPE_METHODS:
        cells = {}
        for name in names:
            seeds = seed_values(recipes[name], _recipe_row(recipes[name], method, hparams), "normalized")
            cells[name] = RecipeCell(*mean_estimate(seeds), tuple(seeds)) if seeds else None
        if not any(cells.values()):
            continue
        env = next(iter(recipes.values())).env
        both = len(names) >= 2 and cells[names[0]] is not None and cells[names[1]] is not None
        diff = mean_difference(cells[names[1]].seeds, cells[names[0]].seeds) if both else None
        out.append(RecipeRow(env, lab, cells, diff))
    return out


class AlphaRow(NamedTuple):
    """FCA at one α: % of expert over seeds (with its t-interval), and its adversary's final loss against the reference
    predictor of a_{t−1} from a_t alone (means over seeds; None where the files predate them)."""

    method: str
    hparams: dict
    cell: RecipeCell
    adversary: float | None
    reference: float | None


def alpha_rows(m: Group) -> list[AlphaRow]:
    """Every FCA configuration of group `m` (both variants), in α order: the α sensitivity."""
    out = []
    for method in ("fca", "fca-ib"):
        for row in sorted(method_rows(m, method), key=lambda r: tuple(sorted(r["hparams"].items()))):
            seeds = seed_values(m, row, "normalized")
            if not seeds:
                continue
            runs = [r for r in m.runs if r["method"] == method and r["hparams"] == row["hparams"]
                    and r["status"] == "ok"]
            finals = [r.get("train_final") or {} for r in runs]

            def mean_of(k, finals=finals):
                values = [f[k] for f in finals if f.get(k) is not None]
                return float(np.mean(values)) if values else None

            out.append(AlphaRow(method, row["hparams"], RecipeCell(*mean_estimate(seeds), tuple(seeds)),
                                mean_of("adversary_loss"), mean_of("reference_loss")))
    return out


# -- the paper's budget with the paper's recipe: the same policies over training, beside Table 5 -------------------

# The methods of the issue's 300k table, (label, method, hparams): None for FCA's task default (`_recipe_row`; a
# method without α, PALR, its first configuration), "tau" for the softmax at the paper's τ of the task (`PAPER_TAU`).
# PALR: issue 58's one method that cleared BC-OH at 30k with FCA's expert.
BUDGET_METHODS = (("BC-SO", "bc-so", {}), ("BC-OH", "bc-oh", {}), (PAPER_STEP_LABEL, "ours-step", PAPER_STEP),
                  ("Ours, softmax at the paper's τ", "ours-softmax", "tau"), ("FCA (TCA)", "fca", None),
                  ("FCA (TCA + IB)", "fca-ib", None), ("PALR", "palr", None), (CEILING_LABEL, CEILING, {}))


class BudgetPoint(NamedTuple):
    """One configuration at one iteration of its runs (an `eval_at` point or the end): % of expert and mean return
    over seeds, each with its 95% t-interval (None where no seed recorded it), the diagnostics there, and the
    validation loss (BC's unweighted loss on the held-out rows; median and range over seeds, None where no seed
    recorded it): what the policy fits offline beside how it drives."""

    iteration: int
    normalized: RecipeCell | None
    returns: RecipeCell | None
    diagnostics: PolicyDiagnostics
    val_loss: Spread | None = None


class BudgetRow(NamedTuple):
    """One method of one task's paper-budget group: the group's name in tables (`task`: the task's title, or the
    task and its setting, "Hopper (FCA's expert, raw labels)"), its points in iteration order, the supplement's Table
    5 return for it (None: Table 5 has no such row), and which hyperparameters ran."""

    env: str
    task: str
    label: str
    method: str
    hparams: dict
    points: tuple[BudgetPoint, ...]
    paper: float | None

    def at(self, iteration: int) -> BudgetPoint | None:
        return next((p for p in self.points if p.iteration == iteration), None)


def paper_budget_groups(merged: Merged) -> list[Group]:
    """The groups of the paper's protocol (mujoco-state, any split) under the `bn-mlp` recipe trained for the `paper`
    preset's iterations: the issue's 300k table, one group per state task, in task order."""
    return [m for key, m in ordered(merged) if key.env in MUJOCO and key.obs == "pos"
            and all(src.preset == "paper" and trained_its_preset(src) for src in m.sources)
            and m.protocol.get("variant_of") == STATE
            and m.protocol.get("recipe") == "bn-mlp" and not other_setting(m.protocol)]


def budget_rows(m: Group, task: str | None = None) -> list[BudgetRow]:
    """`BUDGET_METHODS` that ran in group `m`, each at every iteration its runs were evaluated at (`Budget.eval_at`,
    then the end), with Table 5's return beside BC-SO, BC-OH, Ours (step THR 10% W 5) and FCA (the paper's FCA
    has the information bottleneck: beside TCA + IB, or beside TCA where IB did not run). `task` names the group in
    tables (default: the task's title)."""
    end = int(m.sources[0].config["iterations"])
    ib = bool(method_rows(m, "fca-ib"))
    table5 = {"bc-so": "bc-so", "bc-oh": "bc-oh", "fca-ib": "fca", **({} if ib else {"fca": "fca"})}
    out = []
    for lab, method, hparams in BUDGET_METHODS:
        if hparams == "tau":
            if m.env not in PAPER_TAU:
                continue
            hparams = {"tau": PAPER_TAU[m.env]}
            lab = f"Ours, softmax τ {hparams['tau']:g}"
        row = _recipe_row(m, method, hparams)
        if row is None:
            continue
        alpha = row["hparams"].get("alpha")
        if alpha is not None and alpha != tasks.get(m.env).fca_alpha:   # FCA at another α than the task's own
            lab = f"{lab}, α {alpha:g}"
        runs = sorted(ok_runs(m, row["method"], row["hparams"]), key=lambda r: r.get("seed", 0))
        points = []
        for iteration in sorted({a["iteration"] for r in runs for a in r.get("at") or ()} | {end}):
            at = [a for r in runs if (a := run_at(r, iteration, end))]
            points.append(BudgetPoint(iteration,
                                      mean_cell([a["eval"]["normalized"] for a in at
                                             if is_finite(a["eval"].get("normalized"))]),
                                      mean_cell([a["eval"]["return_mean"] for a in at
                                             if is_finite(a["eval"].get("return_mean"))]),
                                      policy_diagnostics(at),
                                      spread([((a.get("losses") or {}).get("val") or {}).get("unweighted")
                                              for a in at])))
        key = "ours" if method == "ours-step" and row["hparams"] == PAPER_STEP else table5.get(method)
        out.append(BudgetRow(m.env, task or tasks.get(m.env).title, lab, method, dict(row["hparams"]), tuple(points),
                             None if key is None else float(PAPER_TABLE5[key][m.env])))
    return out


def budget_differences(rows: Sequence[BudgetRow]) -> list[tuple[str, dict[int, Interval]]]:
    """One task's differences over seeds, in points of % of expert, at each iteration both arms were evaluated:
    BC-OH − BC-SO (what the history adds), then every other method − BC-OH (does it beat the copycat?).
    `[(label, {iteration: Interval})]`, pairs without a common point left out."""
    by = {r.method: r for r in rows}
    pairs = [("BC-OH − BC-SO", by.get("bc-oh"), by.get("bc-so"))]
    pairs += [(f"{r.label} − BC-OH", r, by.get("bc-oh")) for r in rows if r.method not in ("bc-so", "bc-oh")]
    out = []
    for lab, a, b in pairs:
        if a is None or b is None:
            continue
        diffs = {}
        for p in a.points:
            q = b.at(p.iteration)
            if p.normalized is not None and q is not None and q.normalized is not None:
                diffs[p.iteration] = mean_difference(p.normalized.seeds, q.normalized.seeds)
        if diffs:
            out.append((lab, diffs))
    return out
