"""The methods that came after (`analysis.LATER`) ranked with the paper's: per family of cells (`analysis.ranking`),
one table and one interval figure."""

from __future__ import annotations

from experiments.report.analysis import Family, known_methods, label, ranking
from experiments.report.analysis.ranking import LATER
from experiments.report.figures.builders import ranking_figure
from experiments.report.sections.common import Context, Section, copycat_count, diff_cell, table

FAMILIES = {"copycat": "the settings where copying is expected (FCA's expert, the rough experts, the previous action "
                       "in view)",
            "default": "the default tasks (the shipped experts)"}


def _estimate(e) -> str:
    return "—" if e is None else f"{e.value:.2f} [{e.low:.2f}, {e.high:.2f}]"


def _table(f: Family, names: dict) -> str:
    return table(["method", "IQM, % of expert [95% CI]", "P(> BC-OH) [95% CI]", *f.cells],
                 [[names[r.method], f"{r.iqm.value:.1f} [{r.iqm.low:.1f}, {r.iqm.high:.1f}]", _estimate(r.improvement),
                   *(f"{diff_cell(c.versus) if c.versus else 'reference'}; {copycat_count(c.diagnostics)}"
                     for c in r.cells)] for r in f.ranked])


def ranking_section(ctx: Context) -> list[Section]:
    """"The methods that came after, ranked": per family, the table, and the IQM figure; nothing where no file holds
    one of `LATER`. The title names, in `LATER`'s order, the later methods some family ranks (those that ran in every
    cell of it)."""
    families = ranking(ctx.merged)
    if not families:
        return []
    names = {r.method: label(known_methods(ctx.merged), r.method) for f in families for r in f.ranked}
    body = ctx.figure("ranking.png", "IQM of % of expert per method, with 95% intervals",
                      lambda: ranking_figure(families, names))
    for f in families:
        body += [f"**In {FAMILIES[f.name]}**", "", _table(f, names)]
    later = ", ".join(names[n] for n in LATER if n in names)   # `names`: every method some family ranks
    return [Section(f"The methods that came after{': ' + later if later else ''}, ranked",
                    "Per method: IQM over every cell's seeds and P(> BC-OH), stratified bootstrap; per cell its best "
                    "configuration − BC-OH (bold: above 0) and copycat count.", body)]
