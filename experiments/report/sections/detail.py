"""Per group, everything it ran: where each file came from (`provenance`), the full grid with its heatmaps and
whether the paper's settings are near its best, the loss analysis (the paper's Table 3), and the copycat
diagnostics."""

from __future__ import annotations

import dataclasses
import math
import statistics
import shlex

from ape_jax import methods as methods_lib
from ape_jax import tasks
from ape_jax.pipeline import presets
from ape_jax.pipeline import results as results_lib
from experiments.report import figures
from experiments.report.analysis import (BRAX, Group, best_of, choices, copycat_groups, demonstrator, display_metric,
                                         expert_ape, config_key, file_stem, former_preset, gap, is_rate, label,
                                         loss_rows, ordered, protocol_words, raw_labels, recipe_diagnostics,
                                         recipe_groups)
from experiments.report.sections.common import SETTING_WORDS, Context, Section, expert_text
from experiments.report.sections.diagnostics import group_diagnostics, training_table


def _first_training(m: Group) -> dict[tuple, dict]:
    """The summary rows of the files `m`'s files were trained again to replace (`replaces`), by configuration."""
    return {config_key(row): row for s in m.sources if s.replaces for row in s.replaces["summary"]}


def grid_table(m: Group) -> str:
    """Every configuration: return and % of expert (a task judged by a rate, its reward not its measure: the rate
    in %); where a file of the group was trained again to replace one whose policies were not kept
    (`results.json`'s `replaces`), the first training's return beside it."""
    rows = list(m.summary)
    best = best_of([r for r in rows if r["n_seeds"]])
    rate = is_rate(m)
    first = _first_training(m)
    heads = ([f"{m.metric} %"] if rate else ["return", "% of expert"]) + (["first training"] if first else [])
    lines = ["| method | hparams | seeds | " + " | ".join(heads) + " |", "|---|---|---:|" + "---:|" * len(heads)]
    for r in rows:
        hp = ", ".join(f"{k} {v:g}" for k, v in r["hparams"].items()) or "—"
        lab = label(m.methods, r["method"])
        was = first.get(config_key(r))
        before = ([] if not first else [f"{was['return_mean']:,.1f} ± {was['return_std']:,.1f}"
                                        if was and was["n_seeds"] else "—"])
        ok = r["n_seeds"] and (not rate or r.get("normalized_mean") is not None)
        if not ok:
            lines.append(f"| {lab} | {hp} | {r['n_seeds']} | failed |" + ("" if rate else " |")
                         + "".join(f" {b} |" for b in before))
            continue
        mark = "**" if r is best else ""
        if rate:
            cells = [f"{mark}{r['normalized_mean']:.1f} ± {r['normalized_std']:.1f}{mark}"]
        else:
            cells = [f"{mark}{r['return_mean']:,.1f} ± {r['return_std']:,.1f}{mark}",
                     f"{r['normalized_mean']:.1f}" if r.get("normalized_mean") is not None else "—"]
        lines.append(f"| {mark}{lab}{mark} | {hp} | {r['n_seeds']} | " + " | ".join(cells + before) + " |")
    return "\n".join(lines) + "\n"


def retrained_lines(m: Group) -> list[str]:
    """For a group with files trained again (`replaces`): how far each configuration's mean moved between the two
    trainings, against the standard error of that difference from the two trainings' spreads over seeds (the same
    seeds, other code: were the numbers a property of the seeds, the difference would be far below it)."""
    first = _first_training(m)
    pairs = [(row, first[config_key(row)]) for row in m.summary
             if config_key(row) in first and row["n_seeds"] and first[config_key(row)]["n_seeds"]]
    if not pairs:
        return []
    moved = [(a["return_mean"] - b["return_mean"],
              math.sqrt(a["return_std"] ** 2 / a["n_seeds"] + b["return_std"] ** 2 / b["n_seeds"])) for a, b in pairs]
    beyond = sum(abs(d) > 2 * se for d, se in moved if se > 0)
    ratio = [abs(d) / se for d, se in moved if se > 0]
    return [f"Trained again, {len(pairs)} configuration(s) moved by {min(d for d, _ in moved):+,.1f} to "
            f"{max(d for d, _ in moved):+,.1f} in mean return from the first training (the \"first training\" "
            f"column), a median of {statistics.median(ratio):.2f} standard errors of the difference (from each "
            f"training's std over seeds); {beyond} of {len(ratio)} by more than two, where new seeds would put about "
            "5% beyond two and a median near 0.67.", ""] if ratio else []


def loss_table(m: Group) -> str:
    """The paper's Table 3: mean over seeds of the per-sample loss, all / changepoint / copycat, train / val."""
    keys = [(s, k) for s in ("train", "val") for k in ("unweighted", "changepoint", "copycat")]
    lines = ["| method | " + " | ".join(f"{s}: {'all' if k == 'unweighted' else k}" for s, k in keys) + " |",
             "|---|" + "---:|" * len(keys)]
    for lab, runs in loss_rows(m):
        vals = [sum(r["losses"][s][k] for r in runs) / len(runs) for s, k in keys]
        lines.append(f"| {lab} | " + " | ".join(f"{v:.4f}" for v in vals) + " |")
    return "\n".join(lines) + "\n"


def copycat_table(m: Group) -> str | None:
    """The copycat diagnostics of every configuration that has them (None if no run does).

    Per configuration, the mean over seeds of each seed's mean over evaluation episodes of
    `rollout_ape` (the APE of the policy's own actions, ÷ the training set's mean APE) and
    `imitation_error` (Σ_d (a − a*)² against the expert's action on the policy's own states).
    """
    groups = copycat_groups(m)
    if not groups:
        return None
    expert = expert_ape(m)
    unit = display_metric(m)[1] if display_metric(m)[0] == "normalized" else "% of expert"
    lines = ["| method | hparams | seeds | rollout APE (÷ training mean) | imitation error on own states | "
             f"{unit} |", "|---|---|---:|---:|---:|---:|"]
    if expert is not None:
        lines.append(f"| expert (validation demonstrations) | — | — | {expert:.2f} | 0 | "
                     f"{'—' if is_rate(m) else 100} |")
    for (method, hp), runs in groups.items():
        mean = lambda k: sum(r["eval"][k] for r in runs) / len(runs)  # noqa: E731
        norm = f"{mean('normalized'):.1f}" if all("normalized" in r["eval"] for r in runs) else "—"
        hps = ", ".join(f"{k} {v:g}" for k, v in hp) or "—"
        lines.append(f"| {label(m.methods, method)} | {hps} | {len(runs)} | {mean('rollout_ape'):.3f} | "
                     f"{mean('imitation_error'):.4f} | {norm} |")
    return "\n".join(lines) + "\n"


def _fmt(mean: float, std: float, prefix: str) -> str:
    return f"{mean:.1f} ± {std:.1f}%" if prefix == "normalized" else f"{mean:,.0f} ± {std:,.0f}"


def paper_choices(m: Group) -> list[str]:
    """One sentence per weighting: is the paper's setting within one std over seeds of the grid's best?

    "Within one std" means the gap to the best is at most the larger of the two configurations' std over seeds.
    Where our APE was divided by its training-set mean, the softmax sentence also names the grid value
    nearest to the paper's τ carried over to that scale (the paper's τ acts on the raw APE).
    """
    prefix, _ = display_metric(m)
    pts = " points" if prefix == "normalized" else ""

    def near(chosen: dict, best: dict, rows: list[dict], kind: str) -> str:
        g = gap(chosen, best, prefix)
        if g.is_best:
            return f"{_fmt(*g.chosen, prefix)}, the best of the {len(rows)} {kind} settings"
        where = (f"within one std over seeds ({g.noise:.1f}) of the best" if g.within else
                 f"more than one std over seeds ({g.noise:.1f}) below the best: not near it")
        return (f"{_fmt(*g.chosen, prefix)} vs the best, {SETTING_WORDS[kind](best['hparams'])}, "
                f"{_fmt(*g.best, prefix)}: {g.gap:.1f}{pts} lower, {where}")

    out = []
    for c in choices(m):
        text = f"{c.kind.capitalize()}, the paper's {SETTING_WORDS[c.kind](c.paper)}: " + (
            "not run" if c.chosen is None else near(c.chosen, c.best, c.rows, c.kind)) + "."
        if c.closest is not None:
            text += (f" But our τ acts on the APE divided by its training-set mean ({c.scale:.4f}) and the paper's on "
                     f"the raw APE, so its τ {c.paper['tau']:g} is about τ {c.equivalent:.1f} here (roughly: the "
                     f"paper's APE scale is not ours); the nearest grid value, τ {c.closest['hparams']['tau']:g}: "
                     f"{near(c.closest, c.best, c.rows, c.kind)}.")
        out.append(text)
    return out


def _grid_name(m: Group) -> str:
    """A group's grid figure: `grid-hopper.png` (brax), `grid-hopper-image.png`, `grid-hopper-fca-fs2.png`."""
    return f"grid-{file_stem(m)}.png"


def _protocol_provenance(r: results_lib.Results) -> str:
    """The protocol a results file ran under, as its provenance line says it."""
    if not r.protocol:
        return f"protocol {BRAX} (not recorded: results schema 1 predates protocols; Brax's own settings)"
    p = r.protocol
    skip, own = p.get("frame_skip"), p.get("standard_frame_skip")
    parts = [] if skip is None else [f"frame skip {skip}" + (f" (the environment's own: {own})"
                                                             if own is not None and own != skip else "")]
    if p.get("episode_length"):
        parts.append(f"{p['episode_length']:,}-step episodes")
    if p.get("train_transitions"):
        parts.append(f"{p['train_transitions']:,} training transitions")
    found = demonstrator(r) or {}
    if p.get("expert") is not None or found.get("kind") == "imported" or raw_labels(p):
        parts.append(expert_text(found, p))   # another expert than the task's own, or raw labels: which
    return f"protocol {p.get('name') or BRAX}" + "".join(f", {x}" for x in parts)


def _rebuilt_command(r: results_lib.Results) -> str:
    """The sweep command of a file that does not record its own: a sweep run from Python is given the arguments
    under which today's `presets.resolve` gives the settings it records (`presets.arguments`), its methods and its
    dataset; a schema 1 file (or one whose settings no arguments give) the command as it ran, from its config."""
    cfg = r.config
    methods = [] if cfg.get("methods") == list(methods_lib.default()) else ["--methods", ",".join(cfg["methods"])]
    dataset = ((cfg.get("data") or {}).get("settings") or {}).get("dataset")
    if r.protocol and former_preset(r) is None:  # run from Python: every setting it records, as today's arguments
        try:
            records = dataclasses.replace(r.records(), smoke=bool(cfg.get("smoke")))
            args = presets.arguments(r.env, r.obs, records)
        except presets.SettingsError:  # a file from before schema 3 records part of them: rebuilt from config below
            pass
        else:
            return shlex.join(["python", "-m", "experiments.sweep", "--env", r.env, "--obs", r.obs, *args, *methods,
                               *(["--dataset", dataset] if dataset else [])])
    cmd = f"python -m experiments.sweep --env {r.env} --obs {r.obs} --preset {r.preset}"
    if methods:
        cmd += f" --methods {methods[1]}"
    if former_preset(r) is not None:  # its preset's settings are not today's: the command as it ran then
        return cmd
    # the budget and the grids of its preset (schema 1/2 files ran the mlp recipe, whose grids every recipe shares)
    preset = presets.resolve(r.env, r.obs, preset=r.preset, recipe="mlp") if r.preset in presets.BUDGETS else None
    for key, flag in (("iterations", "--iterations"), ("seeds", "--seeds"), ("eval_episodes", "--eval-episodes")):
        if preset is not None and cfg.get(key) != getattr(preset.budget, key):
            cmd += f" {flag} {cfg[key]}"
    if preset is not None and "step_grid" in cfg and [list(g) for g in preset.recipe.step_grid] != cfg["step_grid"]:
        cmd += " --step-grid " + ",".join(f"{thr:g}:{w:g}" for thr, w in cfg["step_grid"])
    if preset is not None and "softmax_grid" in cfg and list(preset.recipe.softmax_grid) != cfg["softmax_grid"]:
        cmd += " --softmax-grid " + ",".join(f"{tau:g}" for tau in cfg["softmax_grid"])
    return cmd


def provenance(r: results_lib.Results) -> str:
    """The command, protocol and setting one results file came from.

    The command is the one the file records (schema 2), shell-quoted. A file
    that records none is given the command rebuilt from its settings, and says
    why: schema 1 files (upgraded on load: no command, no protocol) predate
    schema 2, whose seeds are derived from each run's identity; a schema 2
    file without a command came from a sweep run from Python.
    """
    cfg = r.config
    if r.command is not None:
        cmd = f"`{shlex.join(r.command)}`"
    elif not r.protocol:
        cmd = (f"`{_rebuilt_command(r)}` (rebuilt from its settings: the file predates results schema 2, written "
               "before seeds were derived from run identity: its numbers came from position-based keys)")
    else:
        cmd = f"`{_rebuilt_command(r)}` (rebuilt from its settings: the sweep ran from Python)"
    if (former := former_preset(r)) is not None:
        cmd += f", `--preset {r.preset}` being the {former} then"
    s, t = r.system or {}, r.timing or {}
    machine = s.get("machine") or "machine not recorded in the file"
    commit = f"`{s.get('commit')}`" + (" with uncommitted changes" if s.get("dirty") else "")
    line = (f"{cmd} — {cfg['iterations']:,} iterations, {cfg['seeds']} seeds, {cfg['eval_episodes']} evaluation "
            f"episodes; {_protocol_provenance(r)}; commit {commit}, jax {s.get('jax')} ({s.get('backend')}, "
            f"{s.get('devices')} device(s)), {machine}; {t.get('total_s', 0):,.0f} s in all"
            + (" (resumed after an interruption: the last process's time only)" if t.get("resumed") else ""))
    if t.get("peak_rss_mb"):
        line += f", peak resident memory {t['peak_rss_mb'] / 1024:.1f} GB"
    width = ((r.settings or {}).get("budget") or {}).get("width")
    line += (f"; {width} configuration(s) per device per call (`budget.width`)" if width else
             "; each program vmapped whole (width 0, as every sweep before `budget.width` ran: its numbers depend "
             "on what trained beside them)")
    if r.replaces:
        was = r.replaces
        commit = (was.get("system") or {}).get("commit")
        line += ("; trained again with its policies kept, to replace "
                 + (f"the file of commit `{commit}`" if commit else "an earlier file") + " whose policies "
                 f"were not (`python -m experiments.evaluate RUN --replaces FILE`; that file's command "
                 f"`{shlex.join(was['command']) if was.get('command') else 'not recorded'}`, its returns in the "
                 "grid's \"first training\" column and its record under `replaces`)")
    chain, again = [], r.reevaluated
    while again:  # the latest evaluation first, each earlier one under "previous"
        chain.append(again)
        again = again.get("previous")
    added = [(", ".join(f"`{f}`" for f in a["fields"]), (a.get("system") or {}).get("commit"))
             for a in reversed(chain) if a.get("fields")]
    if added:
        (fields, commit), *later = added
        line += f"; {fields} added later by `python -m experiments.evaluate` (commit `{commit}`"
        line += "".join(f"), then {fields} (commit `{commit}`" for fields, commit in later)
        line += ", every recorded number reproduced)"
    return line


# -- the sections ------------------------------------------------------------------------------------------------

def group_sections(ctx: Context) -> list[Section]:
    """Per group, in report order: its files' provenance, every configuration with the grid figure, the paper's
    settings against the grid, the loss analysis, and the copycat diagnostics (the columns explained under the
    first diagnostics table of the report: the recipe section's, else the first group's with diagnostics)."""
    explained = bool(recipe_diagnostics(recipe_groups(ctx.merged)))   # the recipe section explained the columns
    out = []
    for key, m in ordered(ctx.merged):
        protocol = f", protocol {protocol_words(m.protocol)}" if m.shows_protocol else ""
        grid = ctx.figure(_grid_name(m), f"{m.title} grid search", lambda: figures.grid_figure(m))
        body = [*(f"- {provenance(r)}" for r in m.sources), "", grid_table(m), *retrained_lines(m), *grid.lines]
        sentences = paper_choices(m)
        if sentences:
            unit = display_metric(m)[1]
            body += [f"Are the paper's settings near the best of our grid? (In {unit}; \"within one std\": "
                     "the gap to the best is at most the larger of the two settings' std over seeds.)", ""]
            body += [f"- {c}" for c in sentences] + [""]
        body += ["Loss analysis (the paper's Table 3; mean over seeds of the per-sample "
                 "loss; changepoints = top 10% APE of each split):", "", loss_table(m)]
        copycat = copycat_table(m)
        if copycat:
            body += ["Copycat diagnostics, from the evaluation rollouts: how predictable each policy's own "
                     "actions are from its previous 9 (ψ's APE, ÷ the training set's mean APE; a policy that "
                     "repeats its last action scores below the expert), and how far its actions are from the "
                     "expert's on the states it visits itself:", "", copycat]
        diagnostics = group_diagnostics(m, explained)
        body += diagnostics + training_table(m)
        explained = explained or bool(diagnostics)
        budget = f", {key.budget:,} iterations" if key.budget else ""   # a longer run of a group is a group apart
        out.append(Section(f"{tasks.get(key.env).title}, `{key.obs}` observations{protocol}{budget}: every "
                           "configuration",
                           body=body, figures=grid.figures))
    return out
