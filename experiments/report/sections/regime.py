"""Table 5 with FCA's expert: per group of `analysis.regime_groups` (FCA's own expert imported, labels raw or
clipped; the rough experts of its kind per task), every method beside the supplement's Table 5, against BC-OH, with
its copycat diagnostics and the history's share of the gap to the full state."""

from __future__ import annotations

import pathlib

from ape_jax import tasks
from experiments.report.analysis import (CEILING, RegimeTable, diagnostics_thresholds, expert_words, regime_groups,
                                         regime_table, verdict)
from experiments.report.sections.common import Context, Section, diff_cell, expert_text, pct_cell, ratio_text, table
from experiments.report.sections.diagnostics import thresholds_line


def _ratio(a: float | None, b: float | None) -> str:
    return "—" if a is None or b is None or b == 0 else f"{a / b:.2f}×"


def _count(judged: int, copycats: int) -> str:
    return "—" if not judged else f"{copycats}/{judged}"


def returns_table(t: RegimeTable) -> str:
    """Each row's % of expert and return with their intervals, its ratio to BC-OH, Table 5's return and ratio beside
    it, and the row − BC-OH in points with its interval (bold where it excludes 0 either way) and verdict."""
    bcoh = None if t.bcoh is None or t.bcoh.returns is None else t.bcoh.returns.mean
    return table(["method", "seeds", "% of expert [95% CI]", "return [95% CI]", "× BC-OH", "Table 5", "× BC-OH",
                  "− BC-OH, points [95% CI]", "verdict"],
                 [[r.label, str(0 if r.normalized is None else len(r.normalized.seeds)), pct_cell(r.normalized),
                   pct_cell(r.returns, ",.0f"), _ratio(None if r.returns is None else r.returns.mean, bcoh),
                   "—" if r.paper is None else f"{r.paper:,.0f}", _ratio(r.paper, t.paper_bcoh),
                   diff_cell(r.versus, either=True), "—" if r.versus is None else verdict(r.versus, r.label, "BC-OH")]
                  for r in t.rows], "l" + "r" * 7 + "l")


def diagnostics_table(t: RegimeTable) -> str:
    """Each row's seeds judged copycat by both verdicts and the median control, predictability and embedding ratios."""
    return table(["method", "copycat, controlled verdict", "copycat, first verdict", "control ratio",
                  "predictability ratio", "embedding ratio"],
                 [[r.label, _count(r.diagnostics.judged, r.diagnostics.controlled),
                   _count(r.diagnostics.read, r.diagnostics.copycats), ratio_text(r.diagnostics.control),
                   ratio_text(r.diagnostics.predictability), ratio_text(r.diagnostics.embedding)] for r in t.rows])


def _share(t: RegimeTable) -> list[str]:
    if t.share is None:
        return []
    cells = {r.method: r.normalized for r in t.rows if r.normalized is not None}
    gap = cells[CEILING].mean - cells["bc-so"].mean if CEILING in cells and "bc-so" in cells else None
    s = t.share
    return [f"The history's share of the gap to BC-full, (BC-OH − BC-SO) / (BC-full − BC-SO): {100 * s.share:.0f}% "
            f"[{100 * s.low:.0f}%, {100 * s.high:.0f}%]" + ("" if gap is None else f" of {gap:+.1f} points") + ".", ""]


def regime_lines(ctx: Context, diagnostics: bool = True) -> list[str]:
    """Per group of `analysis.regime_groups`: its expert and references, `returns_table`, with `diagnostics` also
    `diagnostics_table` and the history's share of the gap to BC-full; nothing where no such group exists."""
    groups = regime_groups(ctx.merged)
    out = []
    for m in groups:
        t = regime_table(m)
        seeds = sorted({len(r.normalized.seeds) for r in t.rows if r.normalized is not None})
        x = m.expert
        out += [f"**{tasks.get(m.env).title}, expert {expert_words(m.protocol)}**: "
                f"{int(m.sources[0].config['iterations']):,} iterations, "
                + (f"{seeds[0]}" if len(seeds) == 1 else f"{seeds[0]}–{seeds[-1]}" if seeds else "no")
                + (" seed" if seeds == [1] else " seeds") + " per configuration.", ""]
        if diagnostics:
            out += [f"- {expert_text(m.demonstrator, m.protocol)}.",
                    "- references (100% and 0%): the expert's return " + (
                        "—" if x.get("return_mean") is None
                        else f"{x['return_mean']:,.0f} ± {x.get('return_std') or 0:,.0f}")
                    + ", a random policy's " + ("—" if x.get("random_return_mean") is None else
                                                f"{x['random_return_mean']:,.0f}") + ".",
                    f"- files: {', '.join(f'`{pathlib.Path(src.path).name}`' for src in m.sources)}.", ""]
        out.append(returns_table(t))
        if diagnostics:
            out += [diagnostics_table(t), *_share(t)]
    if groups and diagnostics:
        out += [thresholds_line(diagnostics_thresholds([src for m in groups for src in m.sources])), ""]
    return out


def regime_section(ctx: Context) -> list[Section]:
    """"Table 5 with FCA's expert" (`regime_lines`); nothing where no group of the regime exists."""
    lines = regime_lines(ctx)
    return [Section("Table 5 with FCA's expert",
                    "An expert of FCA's kind, labels raw or clipped; protocol mujoco-state, split by rows, recipe "
                    "bn-mlp; % of expert and return [95% t-interval]; − BC-OH bold where its interval excludes 0.",
                    lines)] if lines else []


def regime_summary(ctx: Context) -> list[Section]:
    """The returns tables of "Table 5 with FCA's expert" (`regime_lines` without diagnostics), for the findings."""
    lines = regime_lines(ctx, diagnostics=False)
    return [Section("Table 5 with FCA's expert", "% of expert and return [95% t-interval]; − BC-OH bold where "
                    "its interval excludes 0.", lines)] if lines else []
