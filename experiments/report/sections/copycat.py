"""Where copycat appears: the copycat map (the history's benefit per frame skip) and the extended map (recipe,
split, training-set size and budget axes, with BC-OH's diagnostics)."""

from __future__ import annotations

from ape_jax import tasks
from experiments.report import figures
from experiments.report.analysis import (STATE, MAP_METHODS, CopycatMap, MapPoint, copycat_map, diagnostics_thresholds,
                                         extended_map, ordered, thousands)
from experiments.report.sections.common import (Context, Section, copycat_count, diff_cell, interval, plus_minus,
                                                ratio_text, table)
from experiments.report.sections.diagnostics import thresholds_line

NAMES = [lab for lab, _, _ in MAP_METHODS]


def _map_cell(cell) -> str:
    return "—" if cell is None else plus_minus(cell.mean, cell.std if cell.n > 1 else None, ".1f")


def copycat_map_table(maps: list[CopycatMap]) -> str:
    """The copycat map as one table: per task and frame skip, BC-SO, BC-OH and Ours (step THR 10% W 5) in % of
    expert (mean ± sd over seeds), the seeds, BC-OH − BC-SO with its 95% CI, and expert − BC-OH."""
    rows = []
    for cm in maps:
        shown = {(r.frame_skip, r.train_transitions) for r in cm.rows}
        for r in cm.rows + [r for r in cm.data_rows if (r.frame_skip, r.train_transitions) not in shown]:
            history = "—" if r.history is None else f"{r.history:+.1f}"
            if (ci := r.history_ci) is not None:
                history = f"{history} {interval(ci.low, ci.high, min(ci.n_a, ci.n_b), '+.1f')}".rstrip()
            train = "—" if r.train_transitions is None else f"{r.train_transitions:,}"
            seeds = " / ".join("—" if c is None else str(c.n) for c in r.cells)
            rows.append([cm.title, str(r.frame_skip), train, r.protocol, *map(_map_cell, r.cells), seeds, history,
                         "—" if r.ceiling is None else f"{r.ceiling:.1f}"])
    return table(["task", "frame skip", "training transitions", "protocol", *NAMES,
                  "seeds (" + " / ".join(n.split(",")[0] for n in NAMES) + ")", "BC-OH − BC-SO [95% CI]",
                  "expert − BC-OH"], rows, "lrrl" + "r" * (len(NAMES) + 3))


def _cells(q: MapPoint) -> list[str]:
    return [tasks.get(q.env).title, f"{q.recipe}, {q.split}{q.variations}", str(q.frame_skip),
            f"{q.train_transitions:,}", thousands(q.run), thousands(q.iteration)]


LEAD = ["task", "recipe, split", "frame skip", "training transitions", "run", "at"]


def _point(q: MapPoint, field: str) -> str:
    return "—" if q.diagnostics is None else ratio_text(getattr(q.diagnostics, field), with_range=False)


def extended_map_section(ctx: Context) -> list[Section]:
    """"Where copycat appears: the map, extended": every mujoco-state-family state group (`analysis.extended_map`), per
    setting (recipe, split), frame skip, training-set size, run length and evaluation point, the three map methods
    in % of expert and BC-OH − BC-SO with its interval; the cells where BC-full ran with the history's share of the
    gap to it; and BC-OH's copycat diagnostics where the files record them. Nothing where the map has no axis beyond
    the copycat map's (one setting, one budget, no diagnostics)."""
    points = extended_map(ctx.merged)
    diagnosed = [q for q in points if q.diagnostics is not None and (q.diagnostics.read or q.diagnostics.absent)]
    if len({q.setting for q in points}) < 2 and len({q.run for q in points}) < 2 and not diagnosed:
        return []
    thresholds = figures.verdict_thresholds(diagnostics_thresholds([src for _, m in ordered(ctx.merged)
                                                                    for src in m.sources]))
    out = ctx.figure("copycat-map-extended.png", "Where copycat appears: the history's benefit and BC-OH's "
                     "diagnostics along frame skip and training-set size",
                     lambda: figures.extended_map_figure(points, figures.MAP_AXES["map"], thresholds))
    out += ctx.figure("copycat-map-training.png", "Where copycat appears: the history's benefit and BC-OH's "
                      "diagnostics over training",
                      lambda: figures.extended_map_figure(points, figures.MAP_AXES["training"], thresholds))
    out.append(table([*LEAD, *NAMES, "BC-OH − BC-SO [95% CI]"],
                     [[*_cells(q), *map(_map_cell, q.cells), diff_cell(q.history)] for q in points], 2))
    if ceiling := [q for q in points if q.ceiling is not None]:
        out += ["Where BC-full (the full state) ran: the history's share of the gap to it, 95% percentile bootstrap "
                "interval.",
                "", table([*LEAD, "BC-full", "(BC-OH − BC-SO) / (BC-full − BC-SO)"],
                          [[*_cells(q), _map_cell(q.ceiling), "—" if (s := q.share) is None else
                            f"{100 * s.share:.0f}% [{100 * s.low:.0f}%, {100 * s.high:.0f}%]"] for q in ceiling], 2)]
    if diagnosed:
        state = any(q.diagnostics.state is not None for q in diagnosed)
        control = any(q.diagnostics.control is not None for q in diagnosed)
        out += ["BC-OH's copycat diagnostics, medians over seeds, where the files record them.", "",
                table([*LEAD, "BC-OH − BC-SO", "embedding ratio", *(["control ratio"] if control else []),
                       "predictability ratio", "copycat", *(["embedding ÷ state", "velocity 1 − R²"] if state else [])],
                      [[*_cells(q), "—" if q.history is None else f"{q.history.diff:+.1f}", _point(q, "embedding"),
                        *([_point(q, "control")] if control else []), _point(q, "predictability"),
                        copycat_count(q.diagnostics), *([_point(q, "state"), _point(q, "velocity")] if state else [])]
                       for q in diagnosed], 2),
                thresholds_line(diagnostics_thresholds([src for _, m in ordered(ctx.merged) for src in m.sources])), ""]
    return [Section("Where copycat appears: the map, extended",
                    f"Every result of the paper's protocol ({STATE}) and its variants, by recipe and split, frame "
                    "skip, training-set size and budget; % of expert, mean ± sd over seeds.", out)]


def copycat_map_section(ctx: Context) -> list[Section]:
    """"The copycat map": per task with mujoco-state-family results at several frame skips (`analysis.copycat_map`), its
    figure and its table; nothing without a map."""
    maps = copycat_map(ctx.merged)
    if not maps:
        return []
    skips = sorted({r.frame_skip for cm in maps for r in cm.rows})
    return [Section("The copycat map: the history's benefit per frame skip",
                    f"Protocol {STATE} at frame skips {', '.join(map(str, skips))}, the same simulated time and data; "
                    "% of expert, mean ± sd over seeds; BC-OH − BC-SO with its 95% Welch t-interval.",
                    [*ctx.figure("copycat-map.png", "The copycat map: % of expert per frame skip",
                                 lambda: figures.copycat_map_figure(maps)), copycat_map_table(maps)])]
