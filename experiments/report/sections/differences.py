"""Differences over seeds: the differences' table (BC-OH − BC-SO and Ours − BC-OH per group, with the returns
figure), and training longer."""

from __future__ import annotations


from ape_jax import tasks
from experiments.report import figures
from experiments.report.analysis import Difference, Group, difference_rows, is_rate, longer_runs, ordered, verdict
from experiments.report.sections.common import Context, Section, interval, return_cell, table


def difference_table(rows: list[Difference]) -> str:
    """The rows of `difference_rows` as a table: per group and comparison, seeds, difference of means, 95% CI
    (none where an arm has one seed, marked wide at two), verdict."""
    return table(["task", "comparison", "seeds", "difference", "95% CI", "verdict"],
                 [[d.title, d.label, f"{d.ci.n_a} / {d.ci.n_b}", f"{d.ci.diff:+,.0f} ({d.unit})",
                   interval(d.ci.low, d.ci.high, min(d.ci.n_a, d.ci.n_b), "+,.0f") or "—", verdict(d.ci, d.a, d.b)]
                  for d in rows], "llrrrl")


def longer_table(rows, base: Group, longer: Group) -> str:
    """`analysis.longer_runs`' rows of one group: each configuration at the base budget and at the longer one."""
    its = lambda m: f"{m.sources[0].config['iterations']:,} iterations"  # noqa: E731
    return table([f"{longer.title}: configuration", its(base), "seeds", its(longer), "seeds"],
                 [[r.label, return_cell(r.base), str(r.base["n_seeds"]), return_cell(r.longer),
                   str(r.longer["n_seeds"])] for r in rows])


def returns_figures(ctx: Context) -> list[str]:
    """The returns figures, one per family of groups (`figures.families`), each after a line naming its family."""
    body = []
    for f in figures.families(figures.returns_groups(ctx.merged)):
        drawn = ctx.figure(f"returns-{f.name}.png", f"{f.heading}: every method per group",
                           lambda f=f: figures.returns_figure(f, ctx.merged))
        body += [f"**{f.heading}.**", "", *drawn] if drawn else []
    return body


# -- the sections ------------------------------------------------------------------------------------------------

def differences_section(ctx: Context) -> list[Section]:
    """"Differences over seeds": the returns figures (`returns_figures`), then per group BC-OH − BC-SO and Ours −
    BC-OH with their Welch t-intervals and verdicts (`analysis.difference_rows`)."""
    boot = difference_rows(ctx.merged)
    body = returns_figures(ctx)
    if not boot and not body:
        return []
    if boot:
        seeds = min(min(d.ci.n_a, d.ci.n_b) for d in boot)
        rates = list(dict.fromkeys(f"{tasks.get(m.env).title}: in {m.metric} rate"
                                   for _, m in ordered(ctx.merged) if is_rate(m)))
        body += ["Differences of means over seeds" + (f" ({'; '.join(rates)})" if rates else "") + ", 95% Welch "
                 f"t-interval (down to {seeds} seed{'s' * (seeds != 1)} per arm; it holds its level at 3–8 seeds in "
                 "simulation, docs/reliability.md).", "", difference_table(boot)]
    return [Section("Differences over seeds", "Ours − BC-OH, and BC-OH − BC-SO, per group.", body)]


def longer_section(ctx: Context) -> list[Section]:
    """"Training longer": each configuration trained for more iterations beside itself at its preset's budget."""
    longer = longer_runs(ctx.merged)
    if not longer:
        return []
    return [Section("Training longer", "Configurations trained again for more iterations, beside their preset's "
                    "budget: return mean ± sd over seeds (% of expert).",
                    [longer_table(rows, base, m) for m, base, rows in longer])]
