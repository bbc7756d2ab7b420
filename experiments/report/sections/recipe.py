"""The paper's recipe and budget: every method under the project's first recipe and the FCA code's (with FCA's α
sensitivity and the diagnostics per recipe), and the paper's 300k budget over training beside Table 5."""

from __future__ import annotations

from ape_jax import tasks
from experiments.report import figures
from experiments.report.analysis import (STATE, BudgetRow, Group, alpha_rows, budget_differences, budget_rows,
                                         cell_title, diagnostics_thresholds, mean_difference, paper_budget_groups,
                                         recipe_diagnostics, recipe_groups, recipe_rows, regime_budget_groups,
                                         thousands, verdict)
from experiments.report.paper import PAPER_STEP_LABEL, PAPER_TABLE5
from experiments.report.sections.common import (Context, Section, copycat_count, diff_cell, hparams_text, pct_cell,
                                                ratio_text, table)
from experiments.report.sections.diagnostics import diagnostics_lines, thresholds_line

# The within-recipe comparisons the paper's question turns on: (a, b) for a − b.
COMPARISONS = (("BC-OH", "BC-SO"), (PAPER_STEP_LABEL, "BC-OH"), ("FCA (TCA)", "BC-OH"), ("FCA (TCA + IB)", "BC-OH"))


def recipe_section(ctx: Context) -> list[Section]:
    """"The paper's recipe": per task, every method under each recipe of one protocol with bn-mlp − mlp, the
    within-recipe differences the paper's question turns on, every FCA setting that ran (the α sensitivity) with its
    adversary's loss beside the reference predictor's, and the diagnostics per task, recipe and configuration."""
    groups = recipe_groups(ctx.merged)
    if not groups:
        return []
    out = []
    for (env, obs, setting), recipes in groups.items():
        rows = recipe_rows(recipes)
        names = [r for r in ("mlp", "bn-mlp") if r in recipes] + [r for r in recipes if r not in ("mlp", "bn-mlp")]
        title = tasks.get(env).title + ("" if obs == "pos" else f" ({obs})")
        out += [f"**{title}**, protocol {setting}:", "",
                table(["method", *(f"recipe {n}" for n in names), "bn-mlp − mlp"],
                      [[r.label, *(pct_cell(r.cells.get(n)) for n in names), diff_cell(r.difference)] for r in rows])]
        within = []
        for n in names:
            cells = {r.label: r.cells.get(n) for r in rows}
            for a, b in COMPARISONS:
                if cells.get(a) is not None and cells.get(b) is not None:
                    ci = mean_difference(cells[a].seeds, cells[b].seeds)
                    within.append([n, f"{a} − {b}", diff_cell(ci), verdict(ci, a, b)])
        if within:
            out.append(table(["recipe", "difference", "points [95% CI]", "verdict"], within, "llrl"))
        for n in names:
            if alphas := alpha_rows(recipes[n]):
                out += [f"FCA's settings on {title}, recipe {n} (adversary and reference: final losses on a_{{t−1}}):",
                        "", table(["method", "hyperparameters", "% of expert", "adversary loss", "reference loss"],
                                  [[a.method, hparams_text(a.hparams), pct_cell(a.cell),
                                    *("—" if v is None else f"{v:.4g}" for v in (a.adversary, a.reference))]
                                   for a in alphas], 2)]
    sources = [src for recipes in groups.values() for m in recipes.values() for src in m.sources]
    out += diagnostics_lines([((title, n, r.label), r) for title, n, r in recipe_diagnostics(groups)],
                             diagnostics_thresholds(sources), "Copycat diagnostics per task, recipe and configuration:",
                             heads=("task", "recipe", "method"))
    return [Section("The paper's recipe against the project's first",
                    "Same protocol, data, budget and seeds; `mlp` the project's first recipe, `bn-mlp` the FCA code's. "
                    "% of expert [95% t-interval].", out)]


def _bcoh_at(rows: list[BudgetRow], iteration: int) -> float | None:
    bcoh = next((r for r in rows if r.method == "bc-oh"), None)
    p = None if bcoh is None else bcoh.at(iteration)
    return None if p is None or p.returns is None or p.returns.mean == 0 else p.returns.mean


def _ratios(r: BudgetRow, its: list[int], field: str) -> str:
    return " → ".join("—" if (p := r.at(i)) is None else ratio_text(getattr(p.diagnostics, field), with_range=False)
                      for i in its)


def _losses(r: BudgetRow, its: list[int]) -> str:
    return " → ".join("—" if (p := r.at(i)) is None or p.val_loss is None else f"{p.val_loss.median:.2g}"
                      for i in its)


def budget_table(rows: list[list[BudgetRow]]) -> str:
    """Per task and method of the paper-budget groups, % of expert at each iteration its runs were evaluated at, the
    return at the end with its interval and ratio to BC-OH, and the supplement's Table 5 beside it."""
    its = sorted({p.iteration for task in rows for r in task for p in r.points})
    end, out = its[-1], []
    for task in rows:
        title, paper_bcoh = task[0].task, PAPER_TABLE5["bc-oh"][task[0].env]
        for r in task:
            ret = None if (last := r.at(end)) is None else last.returns
            bcoh = _bcoh_at(task, end)
            out.append([title, r.label, str(0 if ret is None else len(ret.seeds)),
                        *(pct_cell(None if (q := r.at(i)) is None else q.normalized) for i in its),
                        pct_cell(ret, ",.0f"), "—" if ret is None or bcoh is None else f"{ret.mean / bcoh:.2f}×",
                        "—" if r.paper is None else f"{r.paper:,.0f}",
                        "—" if r.paper is None else f"{r.paper / paper_bcoh:.2f}×"])
    return table(["task", "method", "seeds", *(f"% of expert at {i:,}" for i in its),
                  f"return at {end:,} [95% CI]", "× BC-OH", "Table 5", "× BC-OH"], out, 2)


def budget_differences_table(rows: list[list[BudgetRow]]) -> str:
    """Per task, BC-OH − BC-SO and each other method − BC-OH in points of % of expert at each iteration, with 95%
    Welch t-intervals (`analysis.budget_differences`), bold where the interval is above 0."""
    its = sorted({p.iteration for task in rows for r in task for p in r.points})
    return table(["task", "difference", *(f"at {i:,}" for i in its)],
                 [[task[0].task, lab, *(diff_cell(ci.get(i)) for i in its)]
                  for task in rows for lab, ci in budget_differences(task)], 2)


def _budget_groups(ctx: Context) -> list[tuple[Group, list[BudgetRow]]]:
    """The paper-budget groups with their rows: the shipped experts' per task (`analysis.paper_budget_groups`), then
    Table 5 with FCA's expert at the paper's budget (`analysis.regime_budget_groups`), named by task and setting."""
    return ([(m, budget_rows(m)) for m in paper_budget_groups(ctx.merged)]
            + [(m, budget_rows(m, cell_title(m))) for m in regime_budget_groups(ctx.merged)])


def paper_budget_section(ctx: Context) -> list[Section]:
    """"The paper's budget with the paper's recipe": per group of `_budget_groups`, `budget_table`, the section's
    figure (% of expert and both halves of the copycat verdicts, with their thresholds), `budget_differences_table`
    and the copycat diagnostics at each point."""
    found = _budget_groups(ctx)
    if not found:
        return []
    groups, rows = [m for m, _ in found], [r for _, r in found]
    its = sorted({p.iteration for task in rows for r in task for p in r.points})
    control = any(p.diagnostics.control is not None for task in rows for r in task for p in r.points)
    state = any(p.diagnostics.state is not None for task in rows for r in task for p in r.points)
    diagnostics = [[task[0].task, r.label, _ratios(r, its, "embedding"),
                    *([_ratios(r, its, "control")] if control else []), _ratios(r, its, "predictability"),
                    " → ".join("—" if (q := r.at(i)) is None else copycat_count(q.diagnostics) for i in its),
                    *([_ratios(r, its, "state")] if state else []), _losses(r, its)] for task in rows for r in task]
    thresholds = figures.verdict_thresholds(diagnostics_thresholds([src for m in groups for src in m.sources]))
    body = [budget_table(rows),   # the headline table first: the results page opens with this section
            *ctx.figure("paper-budget.png", "The paper's budget: % of expert and both halves of the copycat "
                        "verdicts against iterations", lambda: figures.budget_figure(rows, thresholds)),
            "Differences in points of % of expert, 95% Welch t-interval (bold: above 0).", "",
            budget_differences_table(rows),
            f"Copycat diagnostics and the validation loss (BC's, on the held-out rows), medians over seeds at "
            f"{' → '.join(thousands(i) for i in its)}.", "",
            table(["task", "method", "embedding ratio", *(["control ratio"] if control else []), "predictability ratio",
                   "copycat", *(["embedding ÷ state"] if state else []), "validation loss"], diagnostics, 2),
            thresholds_line(diagnostics_thresholds([src for m in groups for src in m.sources])), ""]
    return [Section("The paper's budget with the paper's recipe",
                    f"Protocol {STATE}, split by {groups[0].protocol.get('split')}, recipe bn-mlp, learning rate × 0.1 "
                    f"at a third and two thirds; the shipped experts per task, then any expert of FCA's kind (named "
                    f"with its labels); each run evaluated at {', '.join(f'{i:,}' for i in its)} iterations.",
                    body)]


def budget_summary(ctx: Context) -> list[Section]:
    """The paper-budget tables alone (`budget_table`, `budget_differences_table`), for the findings page."""
    rows = [r for _, r in _budget_groups(ctx)]
    if not rows:
        return []
    return [Section("Table 5 at the paper's budget", "% of expert [95% t-interval]; return on the paper's "
                    "scale beside the supplement's Table 5.",
                    [budget_table(rows), "Differences in points of % of expert, 95% Welch t-interval "
                     "(bold: above 0).", "", budget_differences_table(rows)])]
