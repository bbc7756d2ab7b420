"""The state tables: MuJoCo-State per protocol (with the rows against BC-OH and the supplement's Table 5 beside
them) and MuJoCo-Image."""

from __future__ import annotations

from ape_jax import tasks
from experiments.report.analysis import (BRAX, CEILING, CEILING_LABEL, STATE, Group, Key, Merged, best_of,
                                         difference_unit, extra_methods, groups_of, has_ceiling, headline,
                                         history_share, hparams_suffix, in_state_family, known_methods, label,
                                         method_rows, MUJOCO, ordered, paper_step_row, protocols_of, versus_bcoh)
from experiments.report.paper import PAPER_STEP_LABEL, PAPER_TABLE5
from experiments.report.sections.common import Context, Section, diff_cell, return_cell, table


def _generic(lab: str) -> str:
    """A headline label without the configuration a "best" row names (`"Ours, best step (thr 0.2, w 3)"` →
    `"Ours, best step"`): the row's name in a table with one column per task."""
    return lab.split(" (")[0] if lab.startswith("Ours, best") else lab


def _selected(lab: str, row: dict | None) -> str:
    """What a "best" row's cell adds on its own line: the configuration selected in that task; "" otherwise."""
    return f" <br>{hparams_suffix(row)[1:]}" if lab.startswith("Ours, best") and row is not None else ""


def _titles(groups: list[Group]) -> list[str]:
    return [tasks.get(m.env).title for m in groups]


def state_table(merged: Merged, obs: str = "pos", protocol: str = BRAX, groups: list[Group] | None = None) -> str:
    """Every method per MuJoCo task with observations `obs` ("pos": MuJoCo-State, "image": MuJoCo-Image) under
    `protocol` (or of `groups`, one per task): return mean ± sd over seeds (% of expert), the methods besides ours
    those groups ran, our expert and a random policy; BC-full (the full state's ceiling) last where any ran it."""
    groups = groups_of(merged, obs, protocol) if groups is None else groups
    if not groups:
        return ""
    extras = extra_methods({Key(m.env, obs, protocol): m for m in groups})
    heads = [headline(m, extras, known_methods(merged), has_ceiling(groups)) for m in groups]
    rows = [[_generic(lab)] + [return_cell(head[i][1]) + _selected(*head[i]) for head in heads]
            for i, (lab, _) in enumerate(heads[0])]
    experts = [m.expert for m in groups]
    rows.append(["expert (ours)"] + ["—" if x["return_mean"] is None else
                                     f"{x['return_mean']:,.0f} ± {x['return_std'] or 0:,.0f}" for x in experts])
    rows.append(["random policy"] + ["—" if x["random_return_mean"] is None else f"{x['random_return_mean']:,.0f}"
                                     for x in experts])
    return table(["method", *_titles(groups)], rows)


def versus_table(merged: Merged, obs: str = "pos", protocol: str = BRAX) -> str:
    """The state table's rows against BC-OH, per task: each method's mean − BC-OH's over seeds (in `difference_unit`),
    its 95% Welch t-interval, bold where the interval excludes 0 with ≥ 2 seeds per arm; "" if no group has BC-OH."""
    groups = groups_of(merged, obs, protocol)
    extras = extra_methods({Key(m.env, obs, protocol): m for m in groups})
    columns = [versus_bcoh(m, extras, known_methods(merged), has_ceiling(groups)) for m in groups]
    if not any(ci is not None for col in columns for _, _, ci in col):
        return ""
    rows = [[_generic(lab)] + [diff_cell(col[i][2], "+,.0f", either=True)
                               + ("" if col[i][2] is None else _selected(lab, col[i][1])) for col in columns]
            for i, (lab, _, _) in enumerate(columns[0])]
    return table(["method − BC-OH", *_titles(groups)], rows)


def ceiling_table(merged: Merged, obs: str = "pos", protocol: str = BRAX, groups: list[Group] | None = None) -> str:
    """Per task with observations `obs` under `protocol` (or of `groups`), the share of the gap between BC-SO and
    BC-full (BC on the full state, velocities included: the ceiling) that the history recovers, (BC-OH − BC-SO) /
    (BC-full − BC-SO), with its 95% percentile bootstrap interval (`analysis.history_share`) and the gap in return;
    "" where no task ran all three."""
    groups = groups_of(merged, obs, protocol) if groups is None else groups
    shares = [history_share(m) for m in groups]
    if not any(shares):
        return ""

    def cell(m: Group, share) -> str:
        if share is None:
            return "—"
        gap = (best_of(method_rows(m, CEILING))["return_mean"] - best_of(method_rows(m, "bc-so"))["return_mean"]
               if difference_unit(m)[0] == "return_mean" else None)
        return (f"{100 * share.share:.0f}% [{100 * share.low:.0f}%, {100 * share.high:.0f}%]"
                + ("" if gap is None else f" <br>of {gap:+,.0f}"))

    return table(["the history's share of the gap", *_titles(groups)],
                 [["(BC-OH − BC-SO) / (BC-full − BC-SO)", *(cell(m, s) for m, s in zip(groups, shares))]])


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


def paper_table(merged: Merged, protocol: str = BRAX) -> str:
    """Ours under `protocol` next to the supplement's Table 5 (BC-SO, BC-OH, FCA, Ours at step THR 10% W 5).

    Under the mujoco-state family our returns are on the paper's scale (rewards summed over the same simulated time, in
    standard control steps), so each cell is the absolute mean return, ours ± sd over seeds, with the ratio
    to BC-OH of the same source in brackets, and a row for the experts (the paper does not publish its expert's
    return). Under other protocols the returns are on another scale, and only the ratios to BC-OH compare.
    """
    groups = groups_of(merged, "pos", protocol)
    if not groups:
        return ""
    same_scale = in_state_family(protocol)
    known = known_methods(merged)
    # the paper's FCA is the FCA paper's adversary with its information bottleneck: ours with it where it ran
    # (`fca-ib`), else the adversary alone as the FCA code ships it (`fca`); the row names which
    fca = "fca-ib" if any(method_rows(m, "fca-ib") for m in groups) else "fca"
    ours = [{"bc-so": best_of(method_rows(m, "bc-so")), "bc-oh": best_of(method_rows(m, "bc-oh")),
             "fca": best_of(method_rows(m, fca)), "ours": paper_step_row(m),
             "ceiling": best_of(method_rows(m, CEILING))} for m in groups]

    def cell(row: dict | None, bcoh: dict | None) -> str:
        spread = f" ± {row['return_std']:,.0f}" if same_scale and row is not None and row["return_std"] is not None \
            else ""
        return ("—" if row is None or bcoh is None else
                f"{row['return_mean']:,.0f}{spread} ({row['return_mean'] / bcoh['return_mean']:.2f}×)")

    rows = []
    for method in PAPER_TABLE5:
        cells = []
        for m, mine in zip(groups, ours):
            paper, paper_bcoh = PAPER_TABLE5[method][m.env], PAPER_TABLE5["bc-oh"][m.env]
            cells += [f"{paper:,} ({paper / paper_bcoh:.2f}×)", cell(mine[method], mine["bc-oh"])]
        name = PAPER_STEP_LABEL if method == "ours" else label(known, fca if method == "fca" else method)
        rows.append([name, *cells])
    if has_ceiling(groups):   # the paper has no full-state row: ours beside a dash
        rows.append([CEILING_LABEL, *(c for mine in ours for c in ("—", cell(mine["ceiling"], mine["bc-oh"])))])
    if same_scale:
        rows.append(["expert", *(c for m in groups for c in (
            "not published", "—" if m.expert["return_mean"] is None else f"{m.expert['return_mean']:,.0f}"))])
    return table(["method", *(f"{t}: {who}" for t in _titles(groups) for who in ("paper", "ours"))], rows)


# -- the sections ------------------------------------------------------------------------------------------------

CAPTION = "Return mean ± sd over seeds (% of expert); \"best\" rows selected on the evaluation episodes (optimistic)."


def _state_body(merged: Merged, protocol: str) -> list[str]:
    """The state table, the rows against BC-OH, the ceiling's share and Table 5 beside ours, each with its caption."""
    body = [state_table(merged, "pos", protocol)]
    if versus := versus_table(merged, "pos", protocol):
        body += ["Each row − BC-OH, return, 95% Welch t-interval over seeds (bold: excludes 0).", "", versus]
    if ceiling := ceiling_table(merged, "pos", protocol):
        body += ["The history's share of the gap to BC-full (the full state), 95% percentile bootstrap interval.", "",
                 ceiling]
    if protocol in (STATE, BRAX):
        body += ["The supplement's Table 5 beside ours: mean return (" + (
            "the paper's scale" if in_state_family(protocol) else "other scales: compare the ratios")
            + ") and its ratio to BC-OH.", "", paper_table(merged, protocol)]
    return body


def state_sections(ctx: Context) -> list[Section]:
    """MuJoCo-State per protocol, in report order: the paper's (`mujoco-state`) with Table 5 on the same scale, Brax's
    own (`brax`) with Table 5 by ratios, then other protocols. The mujoco-state family's other frame skips feed the
    copycat map instead, and the recipe variants (`analysis.variant_name`) the recipe section."""
    out = []
    for protocol in protocols_of(ctx.merged, "pos"):
        groups = groups_of(ctx.merged, "pos", protocol)
        heading = protocol_heading(groups)
        if protocol == STATE:
            title = f"MuJoCo-State, the paper's protocol ({STATE})"
        elif protocol == BRAX:
            title = "MuJoCo-State, Brax's frame skip (the project's first results)"
        elif not in_state_family(protocol) and not any(m.protocol.get("variant_of") for m in groups):
            title = f"MuJoCo-State, protocol {protocol}"
        else:
            continue
        out.append(Section(title, (f"{heading[0].upper()}{heading[1:]}; p" if heading else "P")
                           + "ositions only (velocities removed). " + CAPTION, _state_body(ctx.merged, protocol)))
    return out


def image_sections(ctx: Context) -> list[Section]:
    """MuJoCo-Image per protocol: the state table of the image groups, then of those seen through the pretrained
    encoders (`perceived_groups`), where either ran."""
    out = []
    for protocol in protocols_of(ctx.merged, "image"):
        groups = groups_of(ctx.merged, "image", protocol)   # empty where only encoders' groups ran this protocol
        former = groups[0].protocol.get("preset") if groups else None
        title = (f"MuJoCo-Image, the {former}" if former else
                 "MuJoCo-Image" + ("" if protocol == BRAX else f", protocol {protocol}"))
        caption = ("The first image preset, kept as it ran: the small conv encoder on 32×32 frames, 5,000 iterations."
                   if former else "From rendered frames. " + CAPTION)
        if groups:
            out.append(Section(title, caption, [t for t in (state_table(ctx.merged, "image", protocol),
                                                            ceiling_table(ctx.merged, "image", protocol)) if t]))
        if perceived := perceived_groups(ctx.merged, protocol):
            encoders = ", ".join(f"{tasks.get(m.env).title} {m.protocol['perception'][:8]}" for m in perceived)
            out.append(Section(f"{title}, through the pretrained encoders",
                               "The same frames seen through each task's pretrained perception encoder, frozen "
                               f"(docs/perception.md; {encoders}): every policy trains on the frames' embeddings. "
                               + CAPTION, [t for t in (state_table(ctx.merged, "image", protocol, perceived),
                                                       ceiling_table(ctx.merged, "image", protocol, perceived)) if t]))
    return out


def perceived_groups(merged: Merged, protocol: str) -> list[Group]:
    """The MuJoCo image groups of `protocol` at their preset's budget whose frames were seen through a frozen
    pretrained encoder, one per task (the first in report order), in task order."""
    found: dict[str, Group] = {}
    for k, m in ordered(merged):
        if (k.env in MUJOCO and k.obs == "image" and k.protocol == protocol and k.budget is None
                and k.perception and ":" not in k.perception):
            found.setdefault(k.env, m)
    return [found[e] for e in MUJOCO if e in found]
