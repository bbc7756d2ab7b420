"""The driving tables' figure (the supplement's Tables 1 and 2): per configuration of a driving group's table, its
success and stuck rates with their 95% t-intervals over seeds, BC-full set apart as the ceiling."""

from __future__ import annotations

from matplotlib.figure import Figure

from experiments.report.analysis import Group, driving_rows, driving_table, is_rate, mean_estimate, per_seed
from experiments.report.figures.primitives import Intervals, interval_bars

# The figure's two panels: the task's main metric (`None`; ToyTown's success) and the inertia failure.
DRIVING_PANELS = (None, "stuck")


def driving_figure(m: Group) -> Figure | None:
    """Success % and stuck % per configuration of driving group `m`'s table (`analysis.driving_rows`, in its order):
    bar = mean over seeds, line = its 95% t-interval clipped to [0, 100], dots = seeds; the ceiling (BC-full) below a
    dashed line, grey. None for a group that is not a driving one (`analysis.driving_table`) or has no rows."""
    table = driving_table(m)
    rows = driving_rows(m) if table is not None else []
    if not rows:
        return None
    panels = []
    for metric in DRIVING_PANELS:
        metric = metric or m.metric
        scale = 100.0 if metric == "stuck" or (metric == m.metric and is_rate(m)) else 1.0
        values = [per_seed(r.runs, metric, scale) for r in rows]
        found = [mean_estimate(v) if len(v) else (None, None, None) for v in values]
        clip = (lambda x: None if x is None else min(max(x, 0.0), 100.0)) if scale == 100.0 else (lambda x: x)
        panels.append(Intervals(f"{metric} %" if scale == 100.0 else metric.replace("_", " "),
                                "% of episodes (95% t-interval over seeds)" if scale == 100.0 else "per episode",
                                [f[0] for f in found], [clip(f[1]) for f in found], [clip(f[2]) for f in found],
                                [list(v) for v in values], (0.0, 100.0) if scale == 100.0 else None))
    name = f"the supplement's Table {table.number} ({table.words})" if table.number else table.words
    ceiling = next((i for i, r in enumerate(rows) if r.ceiling), None)
    return interval_bars([r.label for r in rows], panels,
                         f"{m.title}: {name}\nbar = mean over seeds, line = 95% t-interval, dots = seeds"
                         + ("; below the dashed line the full state's ceiling" if ceiling is not None else ""),
                         apart=ceiling)
