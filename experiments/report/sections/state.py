"""The state tables: MuJoCo-State per protocol (with the rows against BC-OH and the supplement's Table 5 beside
them) and MuJoCo-Image."""

from __future__ import annotations

from ape_jax import tasks
from experiments.report.analysis import (BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, BRAX, CEILING, CEILING_LABEL, FCA, Group,
                                         Key, Merged, best_of, bootstrap_unit, extra_methods, groups_of, has_ceiling,
                                         headline, history_share, hparams_suffix, in_fca_family, known_methods, label,
                                         method_rows, paper_step_row, protocols_of, versus_bcoh)
from experiments.report.paper import PAPER_STEP_LABEL, PAPER_TABLE5
from experiments.report.sections.common import Context, Section, return_cell


def _generic(lab: str) -> str:
    """A headline label without the configuration a "best" row names (`"Ours, best step (thr 0.2, w 3)"` →
    `"Ours, best step"`): the row's name in a table with one column per task."""
    return lab.split(" (")[0] if lab.startswith("Ours, best") else lab


def _selected(lab: str, row: dict | None) -> str:
    """What a "best" row's cell adds on its own line: the configuration selected in that task; "" otherwise."""
    return f" <br>{hparams_suffix(row)[1:]}" if lab.startswith("Ours, best") and row is not None else ""


def state_table(merged: Merged, obs: str = "pos", protocol: str = BRAX) -> str:
    """Every method per MuJoCo task with observations `obs` ("pos": MuJoCo-State, "image": MuJoCo-Image) under
    `protocol`: return mean ± std over seeds (% of expert), the methods besides ours those groups ran, our
    expert and a random policy; BC-full (the full state's ceiling) last where any of the groups ran it."""
    groups = groups_of(merged, obs, protocol)
    if not groups:
        return ""
    extras = extra_methods({Key(m.env, obs, protocol): m for m in groups})
    known = known_methods(merged)
    heads = [headline(m, extras, known, has_ceiling(groups)) for m in groups]
    lines = ["| method | " + " | ".join(tasks.get(m.env).title for m in groups) + " |",
             "|---|" + "---:|" * len(groups)]
    for i, (lab, _) in enumerate(heads[0]):
        cells = []
        for head in heads:
            lab, row = head[i]
            cells.append(return_cell(row) + _selected(lab, row))
        lines.append(f"| {_generic(lab)} | " + " | ".join(cells) + " |")
    experts = [m.expert for m in groups]
    lines.append("| expert (ours) | " + " | ".join("—" if x["return_mean"] is None else
                                                   f"{x['return_mean']:,.0f} ± {x['return_std'] or 0:,.0f}"
                                                   for x in experts) + " |")
    lines.append("| random policy | " + " | ".join("—" if x["random_return_mean"] is None else
                                                   f"{x['random_return_mean']:,.0f}" for x in experts) + " |")
    return "\n".join(lines) + "\n"


def versus_table(merged: Merged, obs: str = "pos", protocol: str = BRAX) -> str:
    """The state table's rows against BC-OH, per task: each method's mean − BC-OH's over seeds (in `bootstrap_unit`),
    its 95% bootstrap CI, bold where the interval excludes 0 with ≥ 2 seeds per arm; "" if no group has BC-OH."""
    groups = groups_of(merged, obs, protocol)
    extras = extra_methods({Key(m.env, obs, protocol): m for m in groups})
    known = known_methods(merged)
    columns = [versus_bcoh(m, extras, known, has_ceiling(groups)) for m in groups]
    if not any(ci is not None for col in columns for _, _, ci in col):
        return ""
    lines = ["| method − BC-OH | " + " | ".join(tasks.get(m.env).title for m in groups) + " |",
             "|---|" + "---:|" * len(groups)]
    for i, (lab, _, _) in enumerate(columns[0]):
        cells = []
        for col in columns:
            _, row, ci = col[i]
            if ci is None:
                cells.append("—")
                continue
            text = f"{ci.diff:+,.0f} [{ci.low:+,.0f}, {ci.high:+,.0f}]"
            bold = min(ci.n_a, ci.n_b) >= 2 and (ci.low > 0 or ci.high < 0)
            cells.append((f"**{text}**" if bold else text) + _selected(lab, row))
        lines.append(f"| {_generic(lab)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def versus_lines(merged: Merged, protocol: str) -> list[str]:
    """`versus_table` of the MuJoCo-State groups under `protocol` with its caption, or nothing."""
    table = versus_table(merged, "pos", protocol)
    if not table:
        return []
    return ["The same rows against BC-OH: each one's mean return − BC-OH's, over seeds, with a 95% percentile "
            f"bootstrap interval (each arm's seeds resampled independently, {BOOTSTRAP_RESAMPLES:,} times; numpy "
            f"seed {BOOTSTRAP_SEED}); **bold** where the interval excludes 0 (≥ 2 seeds per arm). Each arm keeps "
            "its own seeds (each task's \"every configuration\" table below gives them); the \"best\" rows were "
            "selected after the fact, so theirs are optimistic.", "", table]


def ceiling_table(merged: Merged, obs: str = "pos", protocol: str = BRAX) -> str:
    """Per task with observations `obs` under `protocol`, the share of the gap between BC-SO and BC-full (BC on the
    full state, velocities included: the ceiling) that the history recovers, (BC-OH − BC-SO) / (BC-full − BC-SO),
    with its 95% bootstrap interval (`analysis.history_share`); "" where no task ran all three."""
    groups = groups_of(merged, obs, protocol)
    shares = [history_share(m) for m in groups]
    if not any(shares):
        return ""

    def cell(m: Group, share) -> str:
        if share is None:
            return "—"
        gap = (best_of(method_rows(m, CEILING))["return_mean"] - best_of(method_rows(m, "bc-so"))["return_mean"]
               if bootstrap_unit(m)[0] == "return_mean" else None)
        return (f"{100 * share.share:.0f}% [{100 * share.low:.0f}%, {100 * share.high:.0f}%]"
                + ("" if gap is None else f" <br>of {gap:+,.0f}"))

    return "\n".join(["| the history's share of the gap | " + " | ".join(tasks.get(m.env).title for m in groups) + " |",
                      "|---|" + "---:|" * len(groups),
                      "| (BC-OH − BC-SO) / (BC-full − BC-SO) | "
                      + " | ".join(cell(m, share) for m, share in zip(groups, shares)) + " |"]) + "\n"


def ceiling_lines(merged: Merged, obs: str, protocol: str) -> list[str]:
    """`ceiling_table` of the groups with observations `obs` under `protocol` with its caption, or nothing."""
    table = ceiling_table(merged, obs, protocol)
    if not table:
        return []
    return ["BC-full is BC-SO on the full state (velocities included), the same recipe, "
            "budget and rows: what the observation lacks, it sees. The share of the gap between BC-SO and it that "
            "the history recovers, (BC-OH − BC-SO) / (BC-full − BC-SO), over seeds (each arm's best configuration), "
            f"with a 95% percentile bootstrap interval (each arm's seeds resampled independently, "
            f"{BOOTSTRAP_RESAMPLES:,} times; numpy seed {BOOTSTRAP_SEED}); 0% the history adds nothing, 100% it "
            "gives what the full state gives, and the gap itself (BC-full − BC-SO, in return) below. Where the gap "
            "is small the share is noisy, and its interval says so.", "", table]


def _agreed(values) -> object | None:
    """The one value all of `values` share (None if they differ, or any is None)."""
    values = list(values)
    return values[0] if values and values[0] is not None and all(v == values[0] for v in values) else None


def _horizon(p: dict) -> float | None:
    """Simulated time per episode in the environment's standard control steps (at its own frame skip), or None."""
    need = ("episode_length", "frame_skip", "standard_frame_skip")
    if any(not isinstance(p.get(k), (int, float)) or not p.get(k) for k in need):
        return None
    return p["episode_length"] * p["frame_skip"] / p["standard_frame_skip"]


def protocol_heading(groups: list[Group]) -> str:
    """The settings the groups' protocol dicts agree on, for a heading: `"frame skip 1, 500 standard steps of
    simulated time, 20,000 training transitions"`; "" if none is recorded."""
    ps = [m.protocol for m in groups]
    parts = []
    if (skip := _agreed(p.get("frame_skip") for p in ps)) is not None:
        parts.append(f"frame skip {skip}")
    if (h := _agreed(_horizon(p) for p in ps)) is not None:
        parts.append(f"{h:,.0f} standard steps of simulated time")
    if (n := _agreed(p.get("train_transitions") for p in ps)) is not None:
        parts.append(f"{n:,} training transitions")
    if not any(p.get("variant_of") for p in ps) and any(p.get("train_transitions") for p in ps):
        # files before the recipe records: whole episodes apart, the project's first recipe (`mlp`)
        parts.append("split by whole episodes, recipe mlp")
    return ", ".join(parts)


def protocol_details(groups: list[Group]) -> str:
    """One sentence with every setting the groups' protocols record, per task where they differ ("" if none)."""
    ps = {tasks.get(m.env).title: m.protocol for m in groups}

    def each(fmt, key):
        values = {t: p.get(key) for t, p in ps.items()}
        if all(v is None for v in values.values()):
            return None
        if (v := _agreed(values.values())) is not None:
            return fmt(v)
        return ", ".join(f"{t} {fmt(v)}" for t, v in values.items() if v is not None)

    parts = [("the environments' own frame skip", each(str, "standard_frame_skip")),
             ("frame skip", each(str, "frame_skip")),
             ("control steps per episode", each(lambda v: f"{v:,}", "episode_length")),
             ("rewards scaled by", each(lambda v: f"{v:g}", "reward_scale")),
             ("expert steps collected", each(lambda v: f"{v:,}", "collect_transitions")),
             ("training transitions", each(lambda v: f"{v:,}", "train_transitions")),
             ("validation transitions", each(lambda v: f"{v:,}", "val_transitions")),
             ("history", each(str, "history"))]
    parts = [f"{name} {value}" for name, value in parts if value is not None]
    return ("Recorded settings: " + "; ".join(parts) + ".") if parts else ""


def paper_table(merged: Merged, protocol: str = BRAX) -> str:
    """Ours under `protocol` next to the supplement's Table 5 (BC-SO, BC-OH, FCA, Ours at step THR 10% W 5).

    Under the fca family our returns are on the paper's scale (rewards summed over the same simulated time, in
    standard control steps), so each cell is the absolute mean return, ours ± std over seeds, with the ratio
    to BC-OH of the same source in brackets as a secondary number, and a row for the experts (the paper does
    not publish its expert's return). Under other protocols the returns are on another scale, and only the
    ratios to BC-OH compare.
    """
    groups = groups_of(merged, "pos", protocol)
    if not groups:
        return ""
    same_scale = in_fca_family(protocol)
    known = known_methods(merged)
    lines = ["| method | " + " | ".join(f"{tasks.get(m.env).title}: paper | {tasks.get(m.env).title}: ours"
                                       for m in groups) + " |", "|---|" + "---:|" * (2 * len(groups))]
    # the paper's FCA is the FCA paper's adversary with its information bottleneck: ours with it where it ran
    # (`fca-ib`), else the adversary alone as the FCA code ships it (`fca`); the row names which
    fca = "fca-ib" if any(method_rows(m, "fca-ib") for m in groups) else "fca"
    ours = [{"bc-so": best_of(method_rows(m, "bc-so")), "bc-oh": best_of(method_rows(m, "bc-oh")),
             "fca": best_of(method_rows(m, fca)), "ours": paper_step_row(m)} for m in groups]
    for method in PAPER_TABLE5:
        cells = []
        for m, mine in zip(groups, ours):
            paper, paper_bcoh = PAPER_TABLE5[method][m.env], PAPER_TABLE5["bc-oh"][m.env]
            row, bcoh = mine[method], mine["bc-oh"]
            cells.append(f"{paper:,} ({paper / paper_bcoh:.2f}×)")
            spread = f" ± {row['return_std']:,.0f}" if same_scale and row is not None else ""
            cells.append("—" if row is None or bcoh is None else
                         f"{row['return_mean']:,.0f}{spread} ({row['return_mean'] / bcoh['return_mean']:.2f}×)")
        name = PAPER_STEP_LABEL if method == "ours" else label(known, fca if method == "fca" else method)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    if has_ceiling(groups):   # the paper has no full-state row: ours beside a dash
        cells = []
        for m, mine in zip(groups, ours):
            row, bcoh, spread = best_of(method_rows(m, CEILING)), mine["bc-oh"], ""
            if same_scale and row is not None:
                spread = f" ± {row['return_std']:,.0f}"
            cells += ["—", "—" if row is None or bcoh is None else
                      f"{row['return_mean']:,.0f}{spread} ({row['return_mean'] / bcoh['return_mean']:.2f}×)"]
        lines.append(f"| {CEILING_LABEL} | " + " | ".join(cells) + " |")
    if same_scale:
        lines.append("| expert | " + " | ".join(
            "not published | " + ("—" if m.expert["return_mean"] is None else f"{m.expert['return_mean']:,.0f}")
            for m in groups) + " |")
    return "\n".join(lines) + "\n"


# -- the sections ------------------------------------------------------------------------------------------------

SELECTION = ("\"Best\" rows pick the configuration with the highest return on the evaluation episodes "
             "(selection on the test episodes, as the paper's grid search does; optimistic).")
CELLS = ("Return mean ± std over seeds (each seed's mean over the evaluation episodes), and in brackets the "
         "percentage of our expert's return, normalised against a random policy under the same protocol.")


def state_sections(ctx: Context) -> list[Section]:
    """MuJoCo-State per protocol, in report order: the paper's (`fca`) with Table 5 on the same scale, Brax's own
    (`brax`) with Table 5 by ratios, then other protocols. The fca family's other frame skips feed the copycat map
    instead, and the recipe variants (`analysis.variant_name`) the recipe section."""
    out = []
    for protocol in protocols_of(ctx.merged, "pos"):
        groups = groups_of(ctx.merged, "pos", protocol)
        heading, details = protocol_heading(groups), protocol_details(groups)
        cells = CELLS + " " + SELECTION + (f" {details}" if details else "")
        if protocol == FCA:
            horizon = _agreed(_horizon(m.protocol) for m in groups)
            scale = (f"rewards summed over {horizon:,.0f} standard control steps of simulated time, as the paper's"
                     if horizon is not None else "rewards on the standard control step's scale, as the paper's")
            out.append(Section(
                f"MuJoCo-State, the paper's protocol ({FCA})" + (f": {heading}" if heading else ""),
                "Positions only (velocities removed). " + cells,
                [state_table(ctx.merged, "pos", protocol), *versus_lines(ctx.merged, protocol),
                 *ceiling_lines(ctx.merged, "pos", protocol),
                 "The supplement's Table 5 beside it, on the same scale (" + scale + "): each cell the mean "
                 "return, ours ± std over seeds, and in brackets the ratio to BC-OH of the same source. The "
                 "experts differ (the paper does not publish its expert's return), so the ratio is the "
                 "comparison that does not depend on them.", "", paper_table(ctx.merged, protocol)]))
        elif protocol == BRAX:
            out.append(Section(
                "MuJoCo-State, Brax's frame skip, where the history helps (the project's first results)",
                "Positions only (velocities removed), with the environments' own frame skip and episode length. "
                + cells,
                [state_table(ctx.merged, "pos", protocol), *versus_lines(ctx.merged, protocol),
                 *ceiling_lines(ctx.merged, "pos", protocol),
                 "Next to the supplement's Table 5 (its own experts, whose returns it does not give; its returns "
                 "are on another scale than these): mean returns, and in brackets each method's ratio to BC-OH "
                 "of the same source.", "", paper_table(ctx.merged, protocol)]))
        elif not in_fca_family(protocol) and not any(m.protocol.get("variant_of") for m in groups):
            out.append(Section(f"MuJoCo-State, protocol {protocol}" + (f": {heading}" if heading else ""),
                               "Positions only (velocities removed). " + cells,
                               [state_table(ctx.merged, "pos", protocol),
                                *ceiling_lines(ctx.merged, "pos", protocol)]))
    return out


FIRST_IMAGE_WORDS = ("The MuJoCo tasks' `default` image preset until issue 26, kept as it ran: the small conv encoder "
                     "without normalisation on 32×32 frames, 25 demonstrations (20 train), 5,000 iterations, the "
                     "softmax τ 10 beside the step setting. \"Images on a CPU\" measures why its policies do not "
                     "learn on Hopper and Walker2d.")


def image_sections(ctx: Context) -> list[Section]:
    """MuJoCo-Image per protocol: the state table of the image groups."""
    out = []
    for protocol in protocols_of(ctx.merged, "image"):
        groups = groups_of(ctx.merged, "image", protocol)
        details = protocol_details(groups)
        former = groups[0].protocol.get("preset")
        title = (f"MuJoCo-Image, the {former}" if former else
                 "MuJoCo-Image" + ("" if protocol == BRAX else f", protocol {protocol}"))
        out.append(Section(title, ("As MuJoCo-State, from rendered frames (the image presets: see each file's "
                                   "provenance below)." if not former else FIRST_IMAGE_WORDS)
                           + (f" {details}" if details else ""),
                           [state_table(ctx.merged, "image", protocol),
                            *ceiling_lines(ctx.merged, "image", protocol)]))
    return out
