"""The methods that came after (RAP, PALR, MINE) ranked with the paper's: per family of cells
(`analysis.ranking`), one table and one interval figure."""

from __future__ import annotations

from experiments.report.analysis import Family, Ranked, known_methods, label, ranking
from experiments.report.analysis.ranking import LATER
from experiments.report.figures.builders import ranking_figure
from experiments.report.sections.common import Context, Section, copycat_count, diff_cell

FAMILIES = {"copycat": "the copycat regime (FCA's expert, the rough experts, the previous action in view)",
            "default": "the default tasks (the shipped experts)"}
INTRO = ("RAP (Chuang et al. 2022), PALR (Seo et al. 2023) and MINE (PALR's baseline) beside the paper's methods, on "
         "every cell where one of them ran, the paper's protocol and recipe at the `default` budget. Per method: the "
         "IQM of % of expert over every cell's seeds with a stratified bootstrap 95% interval, the probability that "
         "one of its runs beats one of BC-OH's (95% interval), and per cell its best configuration − BC-OH in points "
         "(95% percentile bootstrap; bold where it excludes 0) with its copycat count (controlled verdict / seeds). "
         "Best configuration per cell, as `experiments.compare` picks: optimistic for a method with several.")


def _estimate(e) -> str:
    return "—" if e is None else f"{e.value:.2f} [{e.low:.2f}, {e.high:.2f}]"


def _table(f: Family, names: dict) -> list[str]:
    head = "| method | IQM, % of expert [95% CI] | P(> BC-OH) [95% CI] | " + " | ".join(f.cells) + " |"
    lines = [head, "|---|---:|---:|" + "---:|" * len(f.cells)]
    for r in f.ranked:
        cells = [f"{diff_cell(c.versus) if c.versus else 'reference'}; {copycat_count(c.diagnostics)}"
                 for c in r.cells]
        lines.append(f"| {names[r.method]} | {r.iqm.value:.1f} [{r.iqm.low:.1f}, {r.iqm.high:.1f}] | "
                     f"{_estimate(r.improvement)} | " + " | ".join(cells) + " |")
    return lines + [""]


def _beats(r: Ranked) -> list[str]:
    return [f"{c.cell} ({c.versus.diff:+.1f})" for c in r.cells
            if c.versus is not None and min(c.versus.n_a, c.versus.n_b) >= 2 and c.versus.low > 0]


def ranking_section(ctx: Context) -> list[Section]:
    """"The methods that came after, ranked": per family, the table, the methods significantly above BC-OH in a
    cell (one line, from the intervals), and the IQM figure; nothing where no file holds RAP, PALR or MINE."""
    families = ranking(ctx.merged)
    if not families:
        return []
    known = known_methods(ctx.merged)
    names = {r.method: label(known, r.method) for f in families for r in f.ranked}
    body = []
    for f in families:
        above = [f"{names[r.method]}: {', '.join(b)}" for r in f.ranked if (b := _beats(r))]
        body += [f"**In {FAMILIES[f.name]}**", "", *_table(f, names),
                 "Significantly above BC-OH in a cell: " + ("; ".join(above) if above else "none") + ".", ""]
    drawn = ctx.figure("ranking.png", "IQM of % of expert per method, with 95% intervals",
                       lambda: ranking_figure(families, names))
    return [Section(f"The methods that came after: {', '.join(n.upper() for n in LATER)}, ranked", INTRO,
                    [*drawn.lines, *body], drawn.figures)]
