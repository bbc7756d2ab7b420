"""Table 5 with FCA's expert: per group of `analysis.regime_groups` (FCA's own expert imported, labels raw or
clipped; the rough experts of its kind per task), every method beside the supplement's Table 5, against BC-OH, with
its copycat diagnostics and the history's share of the gap to the full state."""

from __future__ import annotations

import pathlib

from ape_jax import tasks
from experiments.report.analysis import (BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, CEILING, RegimeRow, RegimeTable,
                                         diagnostics_thresholds, expert_words, regime_groups, regime_table, verdict)
from experiments.report.sections.common import Context, Section, expert_text, pct_cell, ratio_text, significant
from experiments.report.sections.diagnostics import thresholds_line

INTRO = ("The paper's protocol (fca, split by rows as FCA's code does) and recipe (fca), with the demonstrations of an "
         "expert of FCA's kind: FCA's own Hopper expert (the CS294 policy the FCA repository ships, a Gaussian "
         "policy whose unbounded mean is the label; imported with `python -m experiments.import_expert`, never "
         "committed: each group names its file's SHA-256 and origin), or a rough expert of that kind the suite "
         "ships. Labels raw: the expert's output as FCA stored it (the executed action clipped); clipped: clipped "
         "to the action range. Each row: % of expert, the mean over seeds with its 95% percentile bootstrap "
         "interval; the mean return with its interval, on the paper's scale, and its ratio to BC-OH; the "
         "supplement's Table 5 beside it (its return and ratio to BC-OH; its one FCA number beside every α, since "
         "it does not say which gave it); and the row − BC-OH in points of % of expert with its interval (each "
         f"arm's seeds resampled independently, {BOOTSTRAP_RESAMPLES:,} times; numpy seed {BOOTSTRAP_SEED}), bold "
         "where it excludes 0 with ≥ 2 seeds per arm, and its verdict. Then the copycat diagnostics per "
         "configuration: the seeds judged copycat by the controlled verdict (against BC-SO trained on the same rows) "
         "and by the first verdict, and the median control, predictability and embedding ratios over seeds (their "
         "range in brackets).")


def _cell(cell, fmt: str = ",.0f") -> str:
    return "—" if cell is None else f"{cell.mean:{fmt}} [{cell.low:{fmt}}, {cell.high:{fmt}}]"


def _ratio(a: float | None, b: float | None) -> str:
    return "—" if a is None or b is None or b == 0 else f"{a / b:.2f}×"


def _difference(ci) -> str:
    """`"+20.0 [+19.5, +20.5]"`, bold where the interval excludes 0 either way with ≥ 2 seeds per arm; "—" for None."""
    if ci is None:
        return "—"
    text = f"{ci.diff:+.1f} [{ci.low:+.1f}, {ci.high:+.1f}]"
    return f"**{text}**" if min(ci.n_a, ci.n_b) >= 2 and (ci.low > 0 or ci.high < 0) else text


def _count(judged: int, copycats: int) -> str:
    return "—" if not judged else f"{copycats}/{judged}"


def _returns_table(t: RegimeTable) -> list[str]:
    bcoh_return = None if t.bcoh is None or t.bcoh.returns is None else t.bcoh.returns.mean
    lines = ["| method | seeds | % of expert [95% CI] | return [95% CI] | × BC-OH | Table 5 | × BC-OH | "
             "− BC-OH, points [95% CI] | verdict |", "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in t.rows:
        seeds = 0 if r.normalized is None else len(r.normalized.seeds)
        lines.append(f"| {r.label} | {seeds} | {pct_cell(r.normalized)} | {_cell(r.returns)} | "
                     f"{_ratio(None if r.returns is None else r.returns.mean, bcoh_return)} | "
                     f"{'—' if r.paper is None else f'{r.paper:,.0f}'} | {_ratio(r.paper, t.paper_bcoh)} | "
                     f"{_difference(r.versus)} | {'—' if r.versus is None else verdict(r.versus, r.label, 'BC-OH')} |")
    return lines + [""]


def _diagnostics_table(t: RegimeTable) -> list[str]:
    lines = ["| method | copycat, controlled verdict | copycat, first verdict | control ratio | predictability ratio "
             "| embedding ratio |", "|---|---:|---:|---:|---:|---:|"]
    for r in t.rows:
        d = r.diagnostics
        lines.append(f"| {r.label} | {_count(d.judged, d.controlled)} | {_count(d.read, d.copycats)} | "
                     f"{ratio_text(d.control)} | {ratio_text(d.predictability)} | {ratio_text(d.embedding)} |")
    return lines + [""]


def _share_line(t: RegimeTable) -> list[str]:
    if t.share is None:
        return []
    cells = {r.method: r.normalized for r in t.rows if r.normalized is not None}
    gap = cells[CEILING].mean - cells["bc-so"].mean if CEILING in cells and "bc-so" in cells else None
    s = t.share
    return [f"The history's share of the gap between BC-SO and BC-full (the full state), (BC-OH − BC-SO) / (BC-full "
            f"− BC-SO) over seeds: {100 * s.share:.0f}% [{100 * s.low:.0f}%, {100 * s.high:.0f}%]"
            + ("" if gap is None else f" of a gap of {gap:+.1f} points") + ".", ""]


def _names(rows: list[RegimeRow]) -> str:
    return "; ".join(f"{r.label} ({r.versus.diff:+.1f} points)" for r in rows) or "none"


def reading(t: RegimeTable, title: str) -> str:
    """One group's plain reading, from its numbers: BC-OH's % of expert and copycat counts, and the rows whose
    interval against BC-OH excludes 0, each way."""
    parts = []
    if t.bcoh is not None and t.bcoh.normalized is not None:
        d = t.bcoh.diagnostics
        judged = (f"the controlled verdict judges it copycat in {d.controlled} of {d.judged} seeds (the first "
                  f"verdict: {d.copycats} of {d.read})" if d.judged else
                  f"the first verdict judges it copycat in {d.copycats} of {d.read} seeds" if d.read else
                  "it has no copycat diagnostics")
        parts.append(f"BC-OH reaches {t.bcoh.normalized.mean:.1f}% of expert; {judged}")
    compared = [r for r in t.rows if r.versus is not None]
    above = [r for r in compared if significant(r.versus)]
    below = [r for r in compared if min(r.versus.n_a, r.versus.n_b) >= 2 and r.versus.high < 0]
    if compared:
        parts.append(f"significantly above BC-OH: {_names(above)}; significantly below: {_names(below)}; "
                     f"{len(compared) - len(above) - len(below)} of {len(compared)} within their intervals")
    return f"{title}: " + ("; ".join(parts) if parts else "nothing to compare") + "."


def regime_section(ctx: Context) -> list[Section]:
    """"Table 5 with FCA's expert": per group of `analysis.regime_groups`, its expert (SHA-256 and origin) and labels,
    the returns table beside Table 5 and against BC-OH, the copycat diagnostics table, the history's share of the
    gap to BC-full, and a plain reading; nothing where no such group exists."""
    groups = regime_groups(ctx.merged)
    if not groups:
        return []
    out, readings = [], []
    for m in groups:
        t = regime_table(m)
        title = f"{tasks.get(m.env).title}, expert {expert_words(m.protocol)}"
        iterations = int(m.sources[0].config["iterations"])
        seeds = sorted({len(r.normalized.seeds) for r in t.rows if r.normalized is not None})
        out += [f"**{title}**: {iterations:,} iterations, "
                + (f"{seeds[0]}" if len(seeds) == 1 else f"{seeds[0]}–{seeds[-1]}" if seeds else "no")
                + (" seed" if seeds == [1] else " seeds") + " per configuration.", "",
                f"- {expert_text(m.demonstrator, m.protocol)}.",
                "- references under this protocol (100% and 0% of expert): the expert's return "
                + ("—" if m.expert.get("return_mean") is None else
                   f"{m.expert['return_mean']:,.0f} ± {m.expert.get('return_std') or 0:,.0f}")
                + ", a random policy's " + ("—" if m.expert.get("random_return_mean") is None else
                                            f"{m.expert['random_return_mean']:,.0f}") + ".",
                f"- files: {', '.join(f'`{pathlib.Path(src.path).name}`' for src in m.sources)} (their commands "
                "in the group's \"every configuration\" section below).", ""]
        out += _returns_table(t) + _diagnostics_table(t) + _share_line(t)
        readings.append(reading(t, title))
    sources = [src for m in groups for src in m.sources]
    out += [thresholds_line(diagnostics_thresholds(sources)), ""]
    out += [f"- {line}" for line in readings] + [""]
    return [Section("Table 5 with FCA's expert: an expert of FCA's kind, labels raw or clipped", INTRO, out)]
