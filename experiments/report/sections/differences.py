"""Differences over seeds: the bootstrap table (BC-OH − BC-SO and Ours − BC-OH per group, with the returns
figure), the plain reading of whether keyframe weighting helps where the history does not, and training longer."""

from __future__ import annotations

import math

from ape_jax import tasks
from experiments.report import figures
from experiments.report.analysis import (BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, BRAX, FCA, CopycatMap, Difference, Group,
                                         Interval, Key, Merged, best_of, bootstrap_rows, bootstrap_unit, copycat_map,
                                         extra_methods, group_title, history_difference, is_rate, known_methods,
                                         longer_runs, method_rows, ordered, ours_differences, percent,
                                         policy_diagnostics, verdict, versus_bcoh)
from experiments.report.paper import PAPER_STEP
from experiments.report.sections.common import (SETTING_WORDS, Context, Section, ci_text, lift, ratio_text,
                                                return_cell, significant)


def bootstrap_table(rows: list[Difference]) -> str:
    """The rows of `bootstrap_rows` as a table: per group and comparison, seeds, difference of means, 95% CI,
    verdict."""
    lines = ["| task | comparison | seeds | difference | 95% CI | verdict |", "|---|---|---:|---:|---:|---|"]
    lines += [f"| {d.title} | {d.label} | {d.ci.n_a} / {d.ci.n_b} | {d.ci.diff:+,.0f} ({d.unit}) | "
              f"[{d.ci.low:+,.0f}, {d.ci.high:+,.0f}] | {verdict(d.ci, d.a, d.b)} |" for d in rows]
    return "\n".join(lines) + "\n"


def _words(ci: Interval, a: str, b: str, better: str, worse: str) -> str:
    """A verdict (`analysis.verdict`) in the plain reading's words: `better` if `a` is, `worse` if `b` is."""
    v = verdict(ci, a, b)
    if v == f"{a} better":
        return better
    if v == f"{b} better":
        return worse
    return "not significant: these seeds cannot tell them apart" if v.startswith("not significant") else v


def plain_reading(merged: Merged, maps: list[CopycatMap]) -> list[str]:
    """Does keyframe weighting help where the history does not? One paragraph per task with results under the
    paper's protocol (`fca`; tasks without any get none), every number from the results:

    - the history: BC-OH − BC-SO under fca with its CI; BC-OH not significantly above BC-SO means the history
      adds nothing these seeds can see, the return signature the paper attributes to copycat; whether BC-OH
      copies is the diagnostics' to say (BC-OH's verdicts where its runs record them, else that they were not
      measured), never inferred from returns;
    - Ours − BC-OH at the paper's step setting, and at the best of our step and softmax grids (selected after
      the fact on the evaluation returns, so optimistic), each with its CI's verdict;
    - where the task has a copycat map or brax results, the history's benefit (in points of % of expert) at
      the largest frame skip and under Brax's own settings, against the fca frame skip's.
    """
    maps_of = {(cm.env, cm.obs): cm for cm in maps}
    out = []
    for key, m in ordered(merged):
        if key.protocol != FCA or key.budget is not None:
            continue
        unit = bootstrap_unit(m)[1]
        number = ",.0f"
        text = [f"**{group_title(key, m.protocol, with_protocol=False)}.**"]
        history = history_difference(m)
        copycat = None
        if history is None:
            text.append("BC-SO and BC-OH did not both run under fca, so these results cannot say whether the "
                        "history helps.")
        elif min(history.n_a, history.n_b) < 2:
            text.append(f"Under fca BC-OH − BC-SO is {history.diff:+{number}} ({unit}), with fewer than 2 seeds "
                        "per arm: no verdict on the history.")
        else:
            copycat = not significant(history)
            where = ("significantly above" if not copycat else
                     "significantly below" if history.high < 0 else "not significantly above")
            meaning = ("the history helps" if not copycat else
                       "the history hurts, the return signature the paper attributes to copycat" if history.high < 0
                       else "the history adds nothing, the return signature the paper attributes to copycat")
            text.append(f"Under fca BC-OH is {where} BC-SO ({history.diff:+{number}} {unit}, "
                        f"{ci_text(history, '+,.0f')}): {meaning}.")
        text.append(_bcoh_diagnosed(m))
        ours = ours_differences(m)
        paper = next(((row, ci) for _, row, ci in ours if row["method"] == "ours-step"
                      and row["hparams"] == PAPER_STEP), None)
        if paper is None:
            text.append(f"Ours at the paper's step setting (THR {percent(PAPER_STEP['thr'])}, W {PAPER_STEP['w']:g}) "
                        "did not run under fca, or BC-OH did not.")
        else:
            ci = paper[1]
            text.append(f"Ours at the paper's step setting (THR {percent(PAPER_STEP['thr'])}, W {PAPER_STEP['w']:g}) "
                        f"− BC-OH: {ci.diff:+{number}} {unit} ({ci_text(ci, '+,.0f')}): "
                        f"{_words(ci, 'Ours', 'BC-OH', 'keyframe weighting beats BC-OH', 'BC-OH beats it')}.")
        grids = [(row, ci) for lab, row, ci in ours[1:]]
        best_row = best_of([row for row, _ in grids])
        if len(method_rows(m, "ours-step")) + len(method_rows(m, "ours-softmax")) <= 1:
            best_row = None   # no grid ran beside the paper's setting: nothing was selected
        if best_row is not None and paper is not None and best_row is paper[0]:
            text.append("The best of our step and softmax grids is that same setting.")
        elif best_row is not None:
            ci = next(c for row, c in grids if row is best_row)
            kind = "softmax" if best_row["method"] == "ours-softmax" else "step"
            text.append(f"The best of our step and softmax grids, {kind} {SETTING_WORDS[kind](best_row['hparams'])} "
                        f"(selected after the fact on these evaluation returns, so optimistic): "
                        f"{ci.diff:+{number}} {unit} ({ci_text(ci, '+,.0f')}): "
                        f"{_words(ci, 'Ours', 'BC-OH', 'it beats BC-OH', 'BC-OH beats it')}.")
        if copycat and paper is not None:
            outcome = {"Ours better": "beats BC-OH", "BC-OH better": "does worse than BC-OH"}.get(
                verdict(paper[1]), "does not detectably beat BC-OH")
            text.append(f"So where the history does not help, keyframe weighting at the paper's setting {outcome} on "
                        "these seeds.")
        extras = extra_methods({key: m})
        others = [(lab, ci) for lab, row, ci in versus_bcoh(m, extras, known_methods(merged))
                  if row is not None and row["method"] in extras and ci is not None and min(ci.n_a, ci.n_b) >= 2]
        if others:
            def listed(pairs):
                return ", ".join(f"{lab} ({ci.diff:+{number}}, {ci_text(ci, '+,.0f')})" for lab, ci in pairs)

            above = [(lab, ci) for lab, ci in others if ci.low > 0]
            below = [(lab, ci) for lab, ci in others if ci.high < 0]
            level = [lab for lab, ci in others if ci.low <= 0 <= ci.high]
            parts = [f"significantly above: {listed(above) if above else 'none'}"]
            if below:
                parts.append(f"significantly below: {listed(below)}")
            if level:
                parts.append(f"not significantly different: {', '.join(level)}")
            text.append(f"The other methods under fca against BC-OH (in {unit}): " + "; ".join(parts) + ".")
        contrast = []
        cm = maps_of.get((key.env, key.obs))
        here = cm.at(m.protocol.get("frame_skip")) if cm else None
        top = next((r for r in reversed(cm.rows) if r.history is not None), None) if cm else None
        if top is not None and here is not None and here.history is not None and top is not here:
            contrast.append(f"at frame skip {top.frame_skip} the history {lift(top.history)}"
                            + (f" ({ci_text(top.history_ci)})" if top.history_ci else "")
                            + f", against {here.history:+.1f} at frame skip {here.frame_skip}"
                            + (f" ({ci_text(here.history_ci)})" if here.history_ci else ""))
        brax = merged.get(Key(key.env, key.obs, BRAX))
        brax_history = None if brax is None else history_difference(brax, "normalized", 1.0)
        if brax_history is not None:
            contrast.append(f"under Brax's own frame skip (brax) {'it' if contrast else 'the history'} "
                            f"{lift(brax_history.diff)} ({ci_text(brax_history)})")
        if contrast:
            text.append("In % of expert: " + "; ".join(contrast) + ".")
        out.append(" ".join(text))
    return out


def _bcoh_diagnosed(m: Group) -> str:
    """Whether group `m`'s BC-OH copies, by its copycat diagnostics: the seeds judged copycat and the median ratios,
    or that its runs record none (files from before the diagnostics)."""
    row = best_of(method_rows(m, "bc-oh"))
    d = policy_diagnostics([r for r in m.runs if row is not None and r["method"] == "bc-oh"
                            and r["hparams"] == row["hparams"]])
    if not d.read:
        return ("BC-OH's policies here were not diagnosed (their files predate the copycat diagnostics), so whether "
                "it copies is not measured.")
    if d.judged:
        return (f"BC-OH's copycat diagnostics judge {d.controlled} of {d.judged} seeds copycat (the controlled "
                f"verdict; the first: {d.copycats} of {d.read}; median control ratio "
                f"{ratio_text(d.control, with_range=False)}, embedding ratio "
                f"{ratio_text(d.embedding, with_range=False)}, predictability ratio "
                f"{ratio_text(d.predictability, with_range=False)}).")
    return (f"BC-OH's copycat diagnostics judge {d.copycats} of {d.read} seeds copycat (median embedding ratio "
            f"{ratio_text(d.embedding, with_range=False)}, predictability ratio "
            f"{ratio_text(d.predictability, with_range=False)}).")


def longer_table(rows, base: Group, longer: Group) -> str:
    """`analysis.longer_runs`' rows of one group: each configuration at the base budget and at the longer one."""
    its = lambda m: f"{m.sources[0].config['iterations']:,} iterations"  # noqa: E731
    lines = [f"| {longer.title}: configuration | {its(base)} | seeds | {its(longer)} | seeds |",
             "|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r.label} | {return_cell(r.base)} | {r.base['n_seeds']} | {return_cell(r.longer)} | "
                     f"{r.longer['n_seeds']} |")
    return "\n".join(lines) + "\n"


# -- the sections ------------------------------------------------------------------------------------------------

def differences_section(ctx: Context) -> list[Section]:
    """"Differences over seeds": the returns figure, then per group BC-OH − BC-SO and Ours − BC-OH with their
    bootstrap intervals and verdicts (`analysis.bootstrap_rows`), and the caveat few seeds call for."""
    boot = bootstrap_rows(ctx.merged)
    returns = ctx.figure("returns.png", "Return per method and environment",
                         lambda: figures.returns_figure(ctx.merged))
    if not boot and not returns.lines:
        return []
    body = list(returns.lines)
    if boot:
        seeds = min(min(d.ci.n_a, d.ci.n_b) for d in boot)
        rates = list(dict.fromkeys(f"{tasks.get(m.env).title}: in {m.metric} rate"
                                   for _, m in ordered(ctx.merged) if is_rate(m)))
        body += ["Per task and protocol, BC-OH − BC-SO (does the history help? the paper reads copycat from it not "
                 "helping) "
                 "and Ours − BC-OH, differences of mean return over seeds"
                 + (f" ({'; '.join(rates)})" if rates else "") + ", with a 95% percentile bootstrap confidence "
                 f"interval (each arm's seeds resampled with replacement, independently, {BOOTSTRAP_RESAMPLES:,} "
                 f"times; numpy seed {BOOTSTRAP_SEED}). The best-step and best-softmax rows were selected after the "
                 "fact on these same evaluation returns, so their differences are optimistic.", "",
                 bootstrap_table(boot),
                 f"Caveat: with {seeds} seed{'s' * (seeds != 1)} per arm each arm has only "
                 f"{math.comb(2 * seeds - 1, seeds)} distinct resamples, so the interval is coarse, and at so few "
                 "seeds the percentile bootstrap is too narrow (it under-covers): read \"better\" as a hint, and "
                 "\"not significant\" as \"these seeds cannot tell\", not as evidence of no effect.", ""]
    return [Section("Differences over seeds: Ours − BC-OH, and BC-OH − BC-SO", body=body, figures=returns.figures)]


def plain_reading_section(ctx: Context) -> list[Section]:
    """"Does keyframe weighting help where the history does not?": `plain_reading`'s paragraphs, task by task."""
    reading = plain_reading(ctx.merged, copycat_map(ctx.merged))
    if not reading:
        return []
    return [Section("Does keyframe weighting help where the history does not?",
                    f"Read from the tables above, task by task, under the paper's protocol ({FCA}); differences of "
                    "mean return over seeds with their 95% bootstrap CIs. The paper reads copycat from the history "
                    "not helping; here that is only the return signature, and whether BC-OH copies is what its "
                    "copycat diagnostics say, where its runs record them.",
                    [f"{paragraph}\n" for paragraph in reading])]


def longer_section(ctx: Context) -> list[Section]:
    """"Training longer": each configuration trained for more iterations beside itself at its preset's budget."""
    longer = longer_runs(ctx.merged)
    if not longer:
        return []
    return [Section("Training longer",
                    "Configurations trained again for more iterations than their preset's (with `--iterations`), "
                    "beside the same configuration at the preset's budget: mean ± std over seeds of each seed's mean "
                    "return, and % of expert. Their differences over seeds are in the bootstrap table above.",
                    [longer_table(rows, base, m) for m, base, rows in longer])]
