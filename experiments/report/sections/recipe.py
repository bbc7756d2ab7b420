"""The paper's recipe and budget: every method under the project's first recipe and the FCA code's (with FCA's α
sensitivity and the diagnostics per recipe), and the paper's 300k budget over training beside Table 5."""

from __future__ import annotations

from ape_jax import tasks
from experiments.report import figures
from experiments.report.analysis import (FCA, BudgetRow, Interval, alpha_rows, bootstrap_difference, budget_differences,
                                         budget_rows, diagnostics_thresholds, paper_budget_groups, recipe_diagnostics,
                                         recipe_groups, recipe_rows, thousands, verdict)
from experiments.report.paper import PAPER_STEP_LABEL, PAPER_TABLE5
from experiments.report.sections.common import Context, Section, ci_text, diff_cell, pct_cell, ratio_text
from experiments.report.sections.diagnostics import diagnostics_lines, thresholds_line


def recipe_section(ctx: Context) -> list[Section]:
    """"The paper's recipe": per task, every method under each recipe of one protocol, fca − mlp, the within-recipe
    differences the paper's question turns on, and every FCA setting that ran (the α sensitivity where several α
    did) with its adversary's loss beside the reference predictor's."""
    groups = recipe_groups(ctx.merged)
    if not groups:
        return []
    explanation = ("The same protocol, data, budget, seeds and evaluation episodes; only the recipe differs. "
                   "`mlp`: the project's first recipe (no normalisation, Flax's default init, Adam β1 0.9, batch "
                   "128). `fca`: the FCA code's (BatchNorm after each encoder layer, LeakyReLU on the embedding, "
                   "xavier-uniform init, Adam β1 0.5, batch 64; `ape_jax.pipeline.presets.RECIPES`). Each cell: % "
                   "of expert, the mean over seeds with its 95% percentile bootstrap interval; fca − mlp: the "
                   "difference of those means in points, with its interval, bold where it excludes 0. FCA rows are "
                   "at the task's α (the FCA code's).")
    out = []
    told = False
    for (env, obs, setting), recipes in groups.items():
        rows = recipe_rows(recipes)
        names = [r for r in ("mlp", "fca") if r in recipes] + [r for r in recipes if r not in ("mlp", "fca")]
        title = tasks.get(env).title + ("" if obs == "pos" else f" ({obs})")
        out += [f"**{title}**, protocol {setting}:", "",
                "| method | " + " | ".join(f"recipe {n}" for n in names) + " | fca − mlp |",
                "|---|" + "---:|" * (len(names) + 1)]
        out += [f"| {r.label} | " + " | ".join(pct_cell(r.cells.get(n)) for n in names)
                + f" | {diff_cell(r.difference)} |"
                for r in rows]
        out += [""]
        lines = []
        for n in names:
            cells = {r.label: r.cells.get(n) for r in rows}
            for a, b in (("BC-OH", "BC-SO"), (PAPER_STEP_LABEL, "BC-OH"), ("FCA (TCA)", "BC-OH"),
                         ("FCA (TCA + IB)", "BC-OH")):
                if cells.get(a) is not None and cells.get(b) is not None:
                    ci = bootstrap_difference(cells[a].seeds, cells[b].seeds)
                    lines.append(f"recipe {n}: {a} − {b} {diff_cell(ci)} ({verdict(ci, a, b)})")
        if lines:
            out += [f"- {line}" for line in lines] + [""]
        for n in names:
            alphas = alpha_rows(recipes[n])
            if alphas:
                intro = ("% of expert [95% bootstrap interval], and the adversary's final loss (its prediction of "
                         "a_{t−1} from the embedding and a_t) beside a reference predictor's from a_t alone, means "
                         "over seeds of each run's last 1% of iterations: an adversary at the reference's loss gets "
                         "nothing about a_{t−1} from the embedding." if not told else "as above.")
                told = True
                out += [f"FCA's settings on {title}, recipe {n}: {intro}", "",
                        "| method | hyperparameters | % of expert | adversary loss | reference loss |",
                        "|---|---|---:|---:|---:|"]
                out += [f"| {a.method} | {', '.join(f'{k} {v:g}' for k, v in a.hparams.items())} | "
                        f"{pct_cell(a.cell)} | " + " | ".join("—" if v is None else f"{v:.4g}"
                                                               for v in (a.adversary, a.reference)) + " |"
                        for a in alphas]
                out += [""]
    sources = [src for recipes in groups.values() for m in recipes.values() for src in m.sources]
    out += diagnostics_lines([((title, n, r.label), r) for title, n, r in recipe_diagnostics(groups)],
                             diagnostics_thresholds(sources), "Copycat diagnostics per trained policy "
                             "(`ape_jax.diagnostics`), per task, recipe and configuration:", explained=False,
                             heads=("task", "recipe", "method"))
    return [Section("The paper's recipe: the FCA code's network and optimiser against the project's first",
                    explanation, out)]


def _ratio_cell(rows: list[BudgetRow], r: BudgetRow, its: list[int]) -> str:
    """`"x"` of `r` at each of `its`, `"—"` where the point is missing; "/" between them."""
    return " / ".join("—" if (p := r.at(i)) is None or p.returns is None or (b := _bcoh_at(rows, i)) is None
                      else f"{p.returns.mean / b:.2f}×" for i in its)


def _bcoh_at(rows: list[BudgetRow], iteration: int) -> float | None:
    bcoh = next((r for r in rows if r.method == "bc-oh"), None)
    p = None if bcoh is None else bcoh.at(iteration)
    return None if p is None or p.returns is None or p.returns.mean == 0 else p.returns.mean


def _ratios(r: BudgetRow, its: list[int], field: str) -> str:
    return " → ".join("—" if (p := r.at(i)) is None else ratio_text(getattr(p.diagnostics, field), with_range=False)
                      for i in its)


def _budget_reading(rows: list[BudgetRow], diffs: list[tuple[str, dict[int, Interval]]]) -> str:
    """One task's plain reading of the paper-budget table, from its numbers."""
    by = {r.method: r for r in rows}
    title = tasks.get(rows[0].env).title
    end = max(p.iteration for r in rows for p in r.points)
    parts = []
    bcoh = by.get("bc-oh")
    if bcoh is not None:
        seen = [(p.iteration, p) for p in bcoh.points if p.normalized is not None]
        parts.append("BC-OH reaches " + ", ".join(f"{p.normalized.mean:.1f}% of expert at {thousands(i)}"
                                                  for i, p in seen))
        judged = [(i, p.diagnostics) for i, p in seen if p.diagnostics.read]
        if judged:
            parts.append("it is judged copycat in " + ", ".join(
                (f"{d.controlled} of {d.judged} seeds at {thousands(i)} (the first verdict: {d.copycats} of "
                 f"{d.read})" if d.judged else f"{d.copycats} of {d.read} seeds at {thousands(i)}")
                for i, d in judged))
    for lab, d in diffs:
        ci = d.get(end)
        if ci is not None:
            a, b = lab.split(" − ")
            parts.append(f"at {thousands(end)} {lab} is {ci.diff:+.1f} points ({ci_text(ci)}; {verdict(ci, a, b)})")
    return f"{title}: " + "; ".join(parts) + "." if parts else f"{title}: nothing to compare."


def paper_budget_section(ctx: Context) -> list[Section]:
    """"The paper's budget with the paper's recipe": per task (`analysis.paper_budget_groups`), every method of
    `analysis.BUDGET_METHODS` at each iteration its runs were evaluated at, in % of expert with bootstrap intervals,
    its return at the end beside the supplement's Table 5 (each source's ratio to BC-OH), the differences the
    copycat question turns on at each point, and the copycat diagnostics at each point, with the section's figure."""
    groups = paper_budget_groups(ctx.merged)
    if not groups:
        return []
    rows = [budget_rows(m) for m in groups]
    its = sorted({p.iteration for task in rows for r in task for p in r.points})
    end = its[-1]
    p = groups[0].protocol
    heading = (f"The paper's budget with the paper's recipe: the same runs at {', '.join(f'{i:,}' for i in its)} "
               "iterations")
    intro = (f"Protocol {FCA}, split by {p.get('split')}, recipe fca (the FCA code's network and optimiser), "
             f"{end:,} iterations with the learning rate × 0.1 at a third and two thirds of the run (the FCA code's "
             "100k and 200k of 300k). Each run's policy was also evaluated, on the same episodes and with the same "
             "diagnostics, at the iterations of `budget.eval_at` before the end, so each column is the same runs "
             "earlier in training (their learning rate not yet decayed where the point comes before 100k). % of "
             "expert: the mean over seeds with its 95% percentile bootstrap interval. The return at the end is on "
             "the paper's scale; the supplement's Table 5 is beside it, and since the experts differ (the paper "
             "does not publish its own), each source's ratio to its own BC-OH is the comparison that does not "
             "depend on them.")
    drawn = ctx.figure("paper-budget.png", "The paper's budget: % of expert and the embedding ratio against "
                       "iterations", lambda: figures.budget_figure(rows))
    out = [*drawn.lines,"| task | method | seeds | " + " | ".join(f"% of expert at {i:,}" for i in its)
            + f" | return at {end:,} [95% CI] | × BC-OH | Table 5 | × BC-OH |",
            "|---|---|---:|" + "---:|" * (len(its) + 4)]
    for task in rows:
        title = tasks.get(task[0].env).title
        paper_bcoh = PAPER_TABLE5["bc-oh"][task[0].env]
        for r in task:
            last = r.at(end)
            ret = last.returns if last is not None else None
            seeds = len(ret.seeds) if ret is not None else 0
            ratio = _ratio_cell(task, r, [end])
            paper = "—" if r.paper is None else f"{r.paper:,.0f}"
            paper_ratio = "—" if r.paper is None else f"{r.paper / paper_bcoh:.2f}×"
            out.append(f"| {title} | {r.label} | {seeds} | " + " | ".join(pct_cell(None if (q := r.at(i)) is None
                                                                                      else q.normalized) for i in its)
                       + " | " + ("—" if ret is None else f"{ret.mean:,.0f} [{ret.low:,.0f}, {ret.high:,.0f}]")
                       + f" | {ratio} | {paper} | {paper_ratio} |")
    out += ["", "Differences over seeds in points of % of expert at each iteration: BC-OH − BC-SO (what the history "
            "adds; the paper reads copycat from it not helping) and each other method − BC-OH (does it beat BC-OH?), "
            "with 95% bootstrap intervals (each arm's seeds resampled independently), bold where the interval "
            "excludes 0.", "", "| task | difference | " + " | ".join(f"at {i:,}" for i in its) + " |",
            "|---|---|" + "---:|" * len(its)]
    diffs = [budget_differences(task) for task in rows]
    state = any(p.diagnostics.state is not None for task in rows for r in task for p in r.points)
    control = any(p.diagnostics.control is not None for task in rows for r in task for p in r.points)
    for task, d in zip(rows, diffs):
        out += [f"| {tasks.get(task[0].env).title} | {lab} | " + " | ".join(diff_cell(ci.get(i)) for i in its) + " |"
                for lab, ci in d]
    out += ["", "The copycat diagnostics at each iteration (medians over seeds, "
            + " → ".join(thousands(i) for i in its)
            + "): the embedding ratio (the embedding probe's held-out error on a_{t−1} ÷ the same probe's from a_t "
            "alone: below 1 the embedding carries the previous action beyond what the current one gives), the "
            "predictability ratio (a ψ-architecture predictor's held-out error on the policy's own rollout actions ÷ "
            "the same on the expert's: below 1 the policy's actions are more predictable from its previous ones "
            "than the expert's)"
            + (", the control ratio (the embedding probe's error ÷ the median of BC-SO's, trained on the same rows "
               "without a history: below 1 the embedding carries a_{t−1} beyond what a policy without a past does)"
               if control else "")
            + ", and the seeds judged copycat out of those " + ("judged (the controlled verdict; the first "
                                                                "verdict's count in brackets)" if control else "read")
            + ("; and beside them, where recorded, the embedding probe's error ÷ the same probe's from the true "
               "state at t (below 1: the embedding carries a_{t−1} beyond what the state itself tells)" if state
               else "") + ".", "",
            "| task | method | embedding ratio | " + ("control ratio | " if control else "")
            + "predictability ratio | copycat |" + (" embedding ÷ state |" if state else ""),
            "|---|---|---:|" + "---:|" * control + "---:|---:|" + ("---:|" if state else "")]

    def copycats(d) -> str:
        return (f"{d.controlled}/{d.judged} ({d.copycats}/{d.read})" if d.judged
                else f"{d.copycats}/{d.read}" + (" (first verdict only)" if control else ""))

    for task in rows:
        title = tasks.get(task[0].env).title
        out += [f"| {title} | {r.label} | {_ratios(r, its, 'embedding')} | "
                + (f"{_ratios(r, its, 'control')} | " if control else "") + f"{_ratios(r, its, 'predictability')} | "
                + " → ".join("—" if (q := r.at(i)) is None or not q.diagnostics.read
                             else copycats(q.diagnostics) for i in its) + " |"
                + (f" {_ratios(r, its, 'state')} |" if state else "") for r in task]
    sources = [src for m in groups for src in m.sources]
    out += ["", thresholds_line(diagnostics_thresholds(sources)), ""]
    out += [f"- {_budget_reading(task, d)}" for task, d in zip(rows, diffs)] + [""]
    return [Section(heading, intro, out, drawn.figures)]
