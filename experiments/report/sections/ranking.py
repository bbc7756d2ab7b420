"""The methods that came after (`analysis.LATER`) ranked with the paper's: per family of cells (`analysis.ranking`),
one table and one interval figure; and the on-policy check where copying is expected (`analysis.onpolicy_check`)."""

from __future__ import annotations

import numpy as np

from experiments.report.analysis import ONPOLICY, Check, Family, known_methods, label, onpolicy_check, ranking
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
    known = known_methods(ctx.merged)
    names = {m: label(known, m) for f in families for m in (*(r.method for r in f.ranked), *dict(f.partial))}
    body = ctx.figure("ranking.png", "IQM of % of expert per method, with 95% intervals",
                      lambda: ranking_figure(families, names))
    for f in families:
        body += [f"**In {FAMILIES[f.name]}**", "", _table(f, names)]
        if f.partial:
            body += ["Not ranked here, as they ran in some of these cells only: " + "; ".join(
                f"{names[m]}, in {' and '.join(cells)}" for m, cells in f.partial) + ".", ""]
    ranked = {r.method for f in families for r in f.ranked}
    later = ", ".join(names[n] for n in LATER if n in ranked)
    return [Section(f"The methods that came after{': ' + later if later else ''}, ranked",
                    "Per method: IQM over every cell's seeds and P(> BC-OH), stratified bootstrap; per cell its best "
                    "configuration − BC-OH (bold: above 0) and copycat count.", body)]


def _reading(c: Check) -> str:
    """The cell's reading. DAgger above BC-OH: the cell is sound (a policy can do better from these demonstrations'
    task), and whether BC-OH copies there (judged copycat by the controlled verdict in some seed) says whether what
    DAgger lifts is copying; a cell where no BC-OH policy copies and the history's interval is above 0 has no
    copying to remedy, whether DAgger clears BC-OH or not."""
    if c.sound is None:
        return "DAgger not run"
    d = c.bcoh.diagnostics
    copies = bool(d.judged and d.controlled)
    honest = bool(d.judged and not d.controlled and c.history is not None and c.history.low > 0)
    if c.sound and copies:
        return f"sound: DAgger clears BC-OH, and BC-OH copies ({d.controlled}/{d.judged}): room for a remedy of copying"
    if c.sound and honest:
        return ("DAgger clears BC-OH, but no BC-OH policy copies and the history helps: on-policy data lifts "
                "something besides copying")
    if c.sound:
        return "sound: DAgger clears BC-OH"
    if honest:
        return ("no copying to remedy: no BC-OH policy judged copycat and the history helps; DAgger does not clear "
                "BC-OH either")
    return "DAgger does not clear BC-OH: something besides copying holds this cell down"


def onpolicy_section(ctx: Context) -> list[Section]:
    """"The on-policy check where copying is expected": per cell, BC-OH (% of expert and copycat count), what the
    history adds (BC-OH − BC-SO), each of `ONPOLICY` against BC-OH with its copycat count, and the cell's reading;
    nothing where neither ran in such a cell."""
    checks = onpolicy_check(ctx.merged)
    if not checks:
        return []
    names = {n: label(known_methods(ctx.merged), n) for n in ONPOLICY}
    ran = [n for n in ONPOLICY if any(n in c.methods for c in checks)]

    def cell(c: Check, name: str) -> str:
        r = c.methods.get(name)
        return "—" if r is None else f"{diff_cell(r.versus)}; {copycat_count(r.diagnostics)}"

    rows = [[c.cell, f"{float(np.mean(c.bcoh.seeds)):.1f}; {copycat_count(c.bcoh.diagnostics)}",
             diff_cell(c.history), *(cell(c, n) for n in ran), _reading(c)] for c in checks]
    return [Section("The on-policy check where copying is expected",
                    "DAgger (on-policy: the expert labels the policy's own states) and HistoryDropout against BC-OH in "
                    "each cell where copying is expected, on the cell's rows, seeds and budget: where DAgger clears "
                    "BC-OH the cell is sound, and an offline remedy that does not clear BC-OH fails there. Points of "
                    "% of expert, 95% Welch t-interval (bold: above 0); copycat counts as in the ranking.",
                    [table(["cell", "BC-OH, % of expert; copycat", "BC-OH − BC-SO",
                            *(f"{names[n]} − BC-OH; copycat" for n in ran), "reading"], rows,
                          "l" + "r" * (2 + len(ran)) + "l")])]
