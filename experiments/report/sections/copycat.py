"""Where copycat appears: the copycat map (the history's benefit per frame skip, with a sentence per task on where
it opens) and the extended map (recipe, split, training-set size and budget axes, with BC-OH's diagnostics)."""

from __future__ import annotations

from ape_jax import tasks
from experiments.report import figures
from experiments.report.analysis import (FCA, MAP_METHODS, CopycatMap, MapPoint, copycat_map, diagnostics_thresholds,
                                         extended_map, ordered, percent, thousands)
from experiments.report.paper import PAPER_STEP
from experiments.report.sections.common import (Context, Section, ci_text, copycat_count, diff_cell, lift,
                                                ratio_text, significant)
from experiments.report.sections.diagnostics import thresholds_line


def _map_cell(cell) -> str:
    return "—" if cell is None else f"{cell.mean:.1f} ± {cell.std:.1f}"


def copycat_map_table(maps: list[CopycatMap]) -> str:
    """The copycat map as one table: per task and frame skip, BC-SO, BC-OH and Ours (step THR 10% W 5) in % of
    expert (mean ± std over seeds), the seeds, BC-OH − BC-SO with its 95% CI, and expert − BC-OH."""
    names = [lab for lab, _, _ in MAP_METHODS]
    lines = ["| task | frame skip | training transitions | protocol | " + " | ".join(names) + " | seeds (" +
             " / ".join(n.split(",")[0] for n in names) + ") | BC-OH − BC-SO [95% CI] | expert − BC-OH |",
             "|---|---:|---:|---|" + "---:|" * (len(names) + 3)]
    for cm in maps:
        shown = {(r.frame_skip, r.train_transitions) for r in cm.rows}
        for r in cm.rows + [r for r in cm.data_rows if (r.frame_skip, r.train_transitions) not in shown]:
            history = "—" if r.history is None else f"{r.history:+.1f}"
            if r.history_ci is not None:
                history += f" [{r.history_ci.low:+.1f}, {r.history_ci.high:+.1f}]"
            train = "—" if r.train_transitions is None else f"{r.train_transitions:,}"
            lines.append(f"| {cm.title} | {r.frame_skip} | {train} | {r.protocol} | "
                         + " | ".join(map(_map_cell, r.cells))
                         + " | " + " / ".join("—" if c is None else str(c.n) for c in r.cells) + f" | {history} | "
                         + ("—" if r.ceiling is None else f"{r.ceiling:.1f}") + " |")
    return "\n".join(lines) + "\n"


def copycat_map_data_sentence(cm: CopycatMap) -> str | None:
    """At frame skip 1, how the history's benefit and BC-OH change with the training-set size (None: one size)."""
    rows = [r for r in cm.data_rows if r.history is not None]
    if len(rows) < 2:
        return None
    parts = [f"with {r.train_transitions:,} training transitions the history {lift(r.history)}"
             + (f" ({ci_text(r.history_ci)})" if r.history_ci else "") for r in rows]
    bcoh = [r for r in cm.data_rows if r.cells[1] is not None]
    text = f"{cm.title}, frame skip 1: " + "; ".join(parts) + "."
    if bcoh:
        text += " BC-OH reaches " + ", ".join(f"{r.cells[1].mean:.1f}% of expert with {r.train_transitions:,}"
                                               for r in bcoh) + "."
    return text


def copycat_map_sentence(cm: CopycatMap) -> str:
    """Where the history's benefit opens along the frame skips of one task's copycat map, from its numbers."""
    rows = [r for r in cm.rows if r.history is not None]
    if len(cm.rows) < 2:
        return copycat_map_data_sentence(cm) or f"{cm.title}: the map has one frame skip."
    if not rows:
        return f"{cm.title}: BC-SO and BC-OH did not both run at any frame skip, so the map cannot say."
    top, rest = rows[-1], rows[-2::-1]
    text = f"{cm.title}: at frame skip {top.frame_skip} the history {lift(top.history)}" + (
        f" ({ci_text(top.history_ci)})" if top.history_ci else "")
    for r in rest:
        words = f"lifts it {r.history:.1f} points" if r.history >= 0 else \
            f"leaves it {-r.history:.1f} points below BC-SO"
        text += f"; at frame skip {r.frame_skip} it {words}" + (f" ({ci_text(r.history_ci)})" if r.history_ci else "")
    text += "."
    tested = [r for r in rows if r.history_ci is not None and min(r.history_ci.n_a, r.history_ci.n_b) >= 2]
    if tested:
        yes = [str(r.frame_skip) for r in tested if significant(r.history_ci)]
        no = [str(r.frame_skip) for r in tested if not significant(r.history_ci)]
        if not yes:
            text += " At no frame skip is BC-OH significantly above BC-SO."
        elif not no:
            text += " BC-OH is significantly above BC-SO at every frame skip."
        else:
            text += (f" BC-OH is significantly above BC-SO at frame skip {', '.join(yes)}, not at "
                     f"{', '.join(no)}.")
    gaps = [r for r in cm.rows if r.ceiling is not None]
    if gaps:
        text += " BC-OH's gap to the expert: " + ", ".join(
            f"{r.ceiling:.1f} points at frame skip {r.frame_skip}" for r in gaps) + "."
    data = copycat_map_data_sentence(cm)
    return text + (f" {data}" if data else "")


def _point_diag(q: MapPoint, field: str) -> str:
    return "—" if q.diagnostics is None else ratio_text(getattr(q.diagnostics, field), with_range=False)


def _judged_cells_lines(judged: list[MapPoint]) -> list[str]:
    """Which diagnosed cells have a BC-OH seed judged copycat: by the controlled verdict where the cells' files record
    a control, and by the first verdict."""
    if not judged:
        return []

    def where(q: MapPoint, copycats: int, of: int) -> str:
        return (f"{tasks.get(q.env).title} {q.setting}, frame skip {q.frame_skip}, {q.train_transitions:,} "
                f"transitions, at {thousands(q.iteration)} of {thousands(q.run)} ({copycats}/{of})")

    def sentence(cells: list[MapPoint], verdict: str, count) -> str:
        copycat = [q for q in cells if count(q)[0]]
        return (f"Of the {len(cells)} cells whose BC-OH policies {verdict}, "
                + (f"{len(copycat)} {'has' if len(copycat) == 1 else 'have'} a seed judged copycat: "
                   + "; ".join(where(q, *count(q)) for q in copycat) if copycat
                   else "none has a seed judged copycat") + ".")

    controlled = [q for q in judged if q.diagnostics.judged]
    out = []
    if controlled:
        out.append(sentence(controlled, "have the controlled verdict",
                            lambda q: (q.diagnostics.controlled, q.diagnostics.judged)))
    out.append(sentence(judged, "were diagnosed" + (", by the first verdict" if controlled else ""),
                        lambda q: (q.diagnostics.copycats, q.diagnostics.read)))
    return [" ".join(out), ""]


def _ceiling_lines(points: list[MapPoint]) -> list[str]:
    """The cells where BC-full (the full state) ran: its % of expert and the history's share of the gap between
    BC-SO and it, (BC-OH − BC-SO) / (BC-full − BC-SO), with its 95% bootstrap interval; nothing where none did."""
    shown = [q for q in points if q.ceiling is not None]
    if not shown:
        return []

    def share(q: MapPoint) -> str:
        s = q.share
        return "—" if s is None else f"{100 * s.share:.0f}% [{100 * s.low:.0f}%, {100 * s.high:.0f}%]"

    return ["The cells where BC-full ran (BC-SO on the full state, velocities included: the ceiling), with the "
            "share of the gap between BC-SO and it that the history recovers, (BC-OH − BC-SO) / (BC-full − BC-SO) "
            "over seeds, with its 95% percentile bootstrap interval (each arm's seeds resampled independently).",
            "", "| task | recipe, split | frame skip | training transitions | run | at | BC-full | "
            "(BC-OH − BC-SO) / (BC-full − BC-SO) |", "|---|---|---:|---:|---:|---:|---:|---:|"]  \
        + [f"| {tasks.get(q.env).title} | {q.recipe}, {q.split}{q.variations} | {q.frame_skip} | "
           f"{q.train_transitions:,} | {thousands(q.run)} | {thousands(q.iteration)} | {_map_cell(q.ceiling)} | "
           f"{share(q)} |" for q in shown] + [""]


def extended_map_section(ctx: Context) -> list[Section]:
    """"Where copycat appears: the map, extended": every fca-family state group (`analysis.extended_map`), per
    setting (recipe, split), frame skip, training-set size, run length and evaluation point, the three map methods
    in % of expert and BC-OH − BC-SO with its interval; then, for the cells whose files record them, BC-OH's
    copycat diagnostics in a table of their own (so files without diagnostics report as before, and adding them
    only adds lines). Nothing where the map has no axis beyond the copycat map's (one setting, one budget, no
    diagnostics)."""
    points = extended_map(ctx.merged)
    diagnosed = [q for q in points if q.diagnostics is not None and (q.diagnostics.read or q.diagnostics.absent)]
    if len({q.setting for q in points}) < 2 and len({q.run for q in points}) < 2 and not diagnosed:
        return []
    names = [lab for lab, _, _ in MAP_METHODS]
    intro = (f"Every result of the paper's protocol ({FCA}) and its variants, on four axes: the recipe (`mlp`, the "
             "project's first, whose map cells split the demonstrations by whole episodes; `fca`, the FCA code's, "
             "split by rows as its code does; a history other than the protocol's 2 observations is named there), "
             "the frame skip, the training-set size, and the budget (the run's length, and for runs evaluated during "
             "training each iteration they were evaluated at). Per cell, BC-SO, "
             f"BC-OH and Ours (step THR {percent(PAPER_STEP['thr'])} W {PAPER_STEP['w']:g}) in % of expert (mean ± "
             "std over seeds), and BC-OH − BC-SO in points "
             "with its 95% bootstrap interval (bold where it excludes 0): copycat was inferred from a small or "
             "negative BC-OH − BC-SO.")
    drawn = ctx.figure("copycat-map-extended.png", "Where copycat appears: the history's benefit and BC-OH's "
                       "diagnostics along each axis", lambda: figures.extended_map_figure(points))
    out = list(drawn.lines)
    # the "recipe, split" column also names a history not the protocol's
    lead = "| task | recipe, split | frame skip | training transitions | run | at | "
    out += [lead + " | ".join(names) + " | BC-OH − BC-SO [95% CI] |", "|---|---|---:|---:|---:|---:|"
            + "---:|" * (len(names) + 1)]

    def cells(q: MapPoint) -> str:
        return (f"| {tasks.get(q.env).title} | {q.recipe}, {q.split}{q.variations} | {q.frame_skip} | "
                f"{q.train_transitions:,} | {thousands(q.run)} | {thousands(q.iteration)} | ")

    out += [cells(q) + " | ".join(map(_map_cell, q.cells)) + f" | {diff_cell(q.history)} |" for q in points]
    out += [""]
    out += _ceiling_lines(points)
    if diagnosed:
        state = any(q.diagnostics.state is not None for q in diagnosed)
        control = any(q.diagnostics.control is not None for q in diagnosed)
        out += ["BC-OH's copycat diagnostics in the cells whose files record them, which test that inference: "
                "the median embedding ratio and predictability ratio over seeds (below 1: the embedding carries "
                "a_{t−1} beyond what a_t gives; the policy's actions are more predictable than the expert's)"
                + (", the median control ratio (below 1: the embedding carries a_{t−1} beyond what BC-SO's, "
                   "trained on the same rows without a history, does)" if control else "")
                + ", and the seeds judged copycat (the controlled verdict where the files record a control, the "
                "first verdict's count beside it)"
                + ("; where recorded, the embedding probe's error ÷ the same probe's from the true state at t "
                   "(below 1: beyond what the state itself tells) and the velocity probe's 1 − R² (near 0: the "
                   "embedding holds the velocity the history is for)" if state else "") + ".", "",
                lead + "BC-OH − BC-SO | embedding ratio | " + ("control ratio | " if control else "")
                + "predictability ratio | copycat |" + (" embedding ÷ state | velocity 1 − R² |" if state else ""),
                "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|" + "---:|" * control
                + ("---:|---:|" if state else "")]
        out += [cells(q) + ("—" if q.history is None else f"{q.history.diff:+.1f}") + f" | "
                f"{_point_diag(q, 'embedding')} | " + (f"{_point_diag(q, 'control')} | " if control else "")
                + f"{_point_diag(q, 'predictability')} | {copycat_count(q.diagnostics)} |"
                + (f" {_point_diag(q, 'state')} | {_point_diag(q, 'velocity')} |" if state else "")
                for q in diagnosed]
        sources = [src for key, m in ordered(ctx.merged) for src in m.sources]
        out += ["", thresholds_line(diagnostics_thresholds(sources)), ""]
        out += _judged_cells_lines([q for q in diagnosed if q.diagnostics.read])
    return [Section("Where copycat appears: the map, extended", intro, out, drawn.figures)]


def copycat_map_section(ctx: Context) -> list[Section]:
    """"The copycat map": per task with fca-family results at several frame skips (`analysis.copycat_map`), its
    figure, its table and a sentence per task on where the history's benefit opens; nothing without a map."""
    maps = copycat_map(ctx.merged)
    if not maps:
        return []
    skips = sorted({r.frame_skip for cm in maps for r in cm.rows})
    drawn = ctx.figure("copycat-map.png", "The copycat map: % of expert per frame skip",
                       lambda: figures.copycat_map_figure(maps))
    return [Section(
        "The copycat map: the history's benefit per frame skip",
        f"The paper's protocol ({FCA}) at frame skips {', '.join(map(str, skips))}: the same simulated time "
        "per episode and the same numbers of training and validation transitions, so the policies differ "
        "only in how often they act. Per frame skip, BC-SO, BC-OH and Ours (step THR "
        f"{percent(PAPER_STEP['thr'])} W {PAPER_STEP['w']:g}) in % of expert (mean ± std over seeds); BC-OH − "
        "BC-SO is what the history adds, in points of % of expert, with a 95% bootstrap CI over seeds; "
        "expert − BC-OH is how far BC-OH is from its ceiling (the expert, 100%). The paper reads copycat from a "
        "small or negative BC-OH − BC-SO (the history not helping); the copycat diagnostics test whether the "
        "policies copy (\"Where copycat appears: the map, extended\", where files record them)."
        + (" The rows at frame skip 1 with other training-set sizes (fca-train5k, fca-train80k) separate "
           "the frame rate from how much of the task the data shows: 20,000 transitions at frame skip 1 "
           "span a quarter of the simulated time 20,000 span at frame skip 4, and 80,000 span the same."
           if any(cm.data_rows for cm in maps) else ""),
        [*drawn.lines, copycat_map_table(maps), *(f"- {copycat_map_sentence(cm)}" for cm in maps), ""],
        drawn.figures)]
