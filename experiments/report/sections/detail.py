"""Per group, everything it ran: where each file came from (`provenance`), the full grid with its heatmaps and the
paper's settings against its best, the loss analysis (the paper's Table 3), and the copycat diagnostics."""

from __future__ import annotations

import math
import pathlib
import shlex

from ape_jax import methods as methods_lib
from ape_jax.pipeline import presets
from ape_jax.pipeline import results as results_lib
from experiments.report import figures
from experiments.report.analysis import (BRAX, Group, Key, best_of, choices, config_key, copycat_groups, demonstrator,
                                         display_metric, encoder_words, expert_ape, file_stem, first_training,
                                         former_preset, gap,
                                         is_rate, label, loss_rows, metric_value, protocol_words, raw_labels,
                                         retrained_shift)
from experiments.report.sections.common import (SETTING_WORDS, Context, Section, expert_text, hparams_text, plus_minus,
                                                table)
from experiments.report.sections.diagnostics import group_diagnostics, training_table
from experiments.results_index import dataset_of, settings_arguments


def grid_table(m: Group) -> str:
    """Every configuration: return and % of expert (a task judged by a rate, its reward not its measure: the rate
    in %), the best in bold where it has 2 seeds or more (one seed's ranking is noise: none is marked); where a file
    of the group was trained again to replace one whose policies were not kept (`results.json`'s `replaces`), the
    first training's return beside it."""
    best = best_of([r for r in m.summary if r["n_seeds"]])
    best = best if best is not None and best["n_seeds"] >= 2 else None
    rate, first = is_rate(m), first_training(m)
    rows = []
    for r in m.summary:
        was = first.get(config_key(r))
        before = [] if not first else [plus_minus(was["return_mean"], was["return_std"], ",.1f")
                                       if was and was["n_seeds"] else "—"]
        mark = "**" if r is best else ""
        if not r["n_seeds"] or (rate and r.get("normalized_mean") is None):
            cells = ["failed"] + ([] if rate else [""])
        elif rate:
            cells = [f"{mark}{plus_minus(r['normalized_mean'], r['normalized_std'], '.1f')}{mark}"]
        else:
            cells = [f"{mark}{plus_minus(r['return_mean'], r['return_std'], ',.1f')}{mark}",
                     f"{r['normalized_mean']:.1f}" if r.get("normalized_mean") is not None else "—"]
        rows.append([f"{mark}{label(m.methods, r['method'])}{mark}", hparams_text(r["hparams"]), str(r["n_seeds"]),
                     *cells, *before])
    heads = ([f"{m.metric} %"] if rate else ["return", "% of expert"]) + (["first training"] if first else [])
    return table(["method", "hparams", "seeds", *heads], rows, 2)


def retrained_line(m: Group) -> list[str]:
    """How far the configurations trained again moved from their first training (`analysis.retrained_shift`)."""
    s = retrained_shift(m)
    return [] if s is None else [
        f"Trained again: {s.n} configuration(s) moved by {s.low:+,.1f} to {s.high:+,.1f} in mean return, a median of "
        f"{s.median_se:.2f} standard errors; {s.beyond} of {s.n} by more than two.", ""]


def loss_table(m: Group) -> str:
    """The paper's Table 3: mean over seeds of the per-sample loss, all / changepoint / copycat, train / val."""
    keys = [(s, k) for s in ("train", "val") for k in ("unweighted", "changepoint", "copycat")]
    return table(["method", *(f"{s}: {'all' if k == 'unweighted' else k}" for s, k in keys)],
                 [[lab, *(f"{sum(r['losses'][s][k] for r in runs) / len(runs):.4f}" for s, k in keys)]
                  for lab, runs in loss_rows(m)])


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
    rows = [] if expert is None else [["expert (validation demonstrations)", "—", "—", f"{expert:.2f}", "0",
                                       "—" if is_rate(m) else "100"]]
    for (method, hp), runs in groups.items():
        mean = lambda k: sum(r["eval"][k] for r in runs) / len(runs)  # noqa: E731
        rows.append([label(m.methods, method), hparams_text(hp), str(len(runs)), f"{mean('rollout_ape'):.3f}",
                     f"{mean('imitation_error'):.4f}",
                     f"{mean('normalized'):.1f}" if all("normalized" in r["eval"] for r in runs) else "—"])
    return table(["method", "hparams", "seeds", "rollout APE (÷ training mean)", "imitation error on own states",
                  unit], rows, 2)


def _value(g: tuple[float, float], prefix: str) -> str:
    sd = None if math.isnan(g[1]) else g[1]  # one seed records no std: the mean alone
    return plus_minus(g[0], sd, ".1f" if prefix == "normalized" else ",.0f")


def choices_table(m: Group) -> str:
    """Per weighting, the paper's setting against the grid's best (`analysis.choices`, `gap`): both values, the gap
    and the noise (the larger std over seeds); where our APE was divided by its mean, also the grid value nearest
    to the paper's τ carried over to that scale; "" where no weighting with a paper setting ran."""
    prefix, unit = display_metric(m)
    rows = []
    for c in choices(m):
        words = SETTING_WORDS[c.kind]
        tried = [(f"{c.kind}, the paper's {words(c.paper)}", c.chosen)]
        if c.closest is not None:
            tried.append((f"{c.kind}, nearest the paper's τ on our APE scale (τ {c.equivalent:.1f}): "
                          f"{words(c.closest['hparams'])}", c.closest))
        for name, row in tried:
            g = None if row is None else gap(row, c.best, prefix)
            noisy = g is not None and not math.isnan(g.noise)  # a std on both sides: a gap can be judged
            rows.append([name, "not run" if g is None else _value(g.chosen, prefix), words(c.best["hparams"]),
                         _value(metric_value(c.best, prefix), prefix),
                         "—" if g is None else f"{g.gap:.1f}", f"{g.noise:.1f}" if noisy else "—",
                         "—" if g is None else "best" if g.is_best else ("yes" if g.within else "no") if noisy
                         else "— (no std)"])
    return table(["setting", unit, "the grid's best", unit, "gap", "larger std", "within one std"], rows,
                 "lrlrrrl") if rows else ""


def _protocol_provenance(r: results_lib.Results) -> str:
    """The protocol a results file ran under, as its provenance line says it."""
    if r.written_schema == 1:
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
    under which today's `presets.resolve` gives the settings it records (`results_index.settings_arguments`, which
    the results index replays by too), its methods and its dataset; a schema 1 file (or one whose settings no
    arguments give) the command as it ran, from its config."""
    cfg = r.config
    methods = [] if cfg.get("methods") == list(methods_lib.default()) else ["--methods", ",".join(cfg["methods"])]
    dataset = dataset_of(r)
    if r.written_schema != 1 and former_preset(r) is None:  # run from Python: every setting, as today's arguments
        try:
            args = settings_arguments(r)
        except presets.SettingsError:  # a file from before schema 3 records part of them: rebuilt from config below
            pass
        else:
            return shlex.join(["python", "-m", "experiments.sweep", *args, *methods,
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
    if preset is not None and "step_grid" in cfg and list(map(list, preset.knob("ours-step").grid)) != cfg["step_grid"]:
        cmd += " --step-grid " + ",".join(f"{thr:g}:{w:g}" for thr, w in cfg["step_grid"])
    if preset is not None and "softmax_grid" in cfg and list(preset.knob("ours-softmax").taus) != cfg["softmax_grid"]:
        cmd += " --softmax-grid " + ",".join(f"{tau:g}" for tau in cfg["softmax_grid"])
    return cmd


def portable(argv) -> list[str]:
    """A recorded command without machine paths: each absolute path (an argument, or the value of `--flag=PATH`)
    becomes its part from its last `runs` folder on (`/home/me/runs/s7/a` → `runs/s7/a`), else its last name."""
    def strip(arg: str) -> str:
        flag, eq, value = arg.partition("=") if arg.startswith("--") and "=" in arg else ("", "", arg)
        if not value.startswith("/"):
            return arg
        parts = pathlib.PurePosixPath(value).parts
        runs = max((i for i, p in enumerate(parts) if p == "runs"), default=None)
        return flag + eq + ("/".join(parts[runs:]) if runs is not None else parts[-1])

    return [strip(str(a)) for a in argv]


def provenance(r: results_lib.Results) -> str:
    """The command, protocol and setting one results file came from, without machine paths (`portable`).

    The command is the one the file records (schema 2), shell-quoted. A file that records none is given the command
    rebuilt from its settings, and says why: schema 1 files (upgraded on load: no command, no protocol) predate
    schema 2, whose seeds are derived from each run's identity; a schema 2 file without a command came from a sweep
    run from Python.
    """
    cfg = r.config
    if r.command is not None:
        cmd = f"`{shlex.join(portable(r.command))}`"
    elif r.written_schema == 1:
        cmd = (f"`{_rebuilt_command(r)}` (rebuilt from its settings: the file predates results schema 2, its seeds "
               "position-based)")
    else:
        cmd = f"`{_rebuilt_command(r)}` (rebuilt from its settings: the sweep ran from Python)"
    if (former := former_preset(r)) is not None:
        cmd += f", `--preset {r.preset}` being the {former} then"
    s, t = r.system or {}, r.timing or {}
    commit = f"`{s.get('commit')}`" + (" with uncommitted changes" if s.get("dirty") else "")
    line = (f"{cmd} — {cfg['iterations']:,} iterations, {cfg['seeds']} seeds, {cfg['eval_episodes']} evaluation "
            f"episodes; {_protocol_provenance(r)}; commit {commit}, jax {s.get('jax')} ({s.get('backend')}, "
            f"{s.get('devices')} device(s)), {s.get('machine') or 'machine not recorded'}; "
            f"{t.get('total_s', 0):,.0f} s in all" + (" (resumed after an interruption: the last process's time)"
                                                    if t.get("resumed") else ""))
    if t.get("peak_rss_mb"):
        line += f", peak resident memory {t['peak_rss_mb'] / 1024:.1f} GB"
    if t.get("peak_device_mb"):
        line += f", peak device memory {t['peak_device_mb'] / 1024:.1f} GB"
    width = ((r.settings or {}).get("budget") or {}).get("width")
    line += (f"; {width} configuration(s) per device per call (`budget.width`)" if width else
             "; each program vmapped whole (width 0)")
    if r.replaces:
        was = r.replaces
        commit = (was.get("system") or {}).get("commit")
        line += ("; trained again with its policies kept, to replace "
                 + (f"the file of commit `{commit}`" if commit else "an earlier file") + " (that file's command "
                 f"`{shlex.join(portable(was['command'])) if was.get('command') else 'not recorded'}`)")
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

def group_title(m: Group) -> str:
    """A group's heading on its task's page: `"Protocol mujoco-state, split by rows, recipe bn-mlp, 300,000
    iterations"`."""
    return (f"Protocol {protocol_words(m.protocol)}" + (f", {m.budget:,} iterations" if m.budget else "")
            + (f", {encoder_words(m.protocol['perception'])}" if m.protocol.get("perception") else ""))


def group_sections(ctx: Context, key: Key) -> list[Section]:
    """Group `key`'s section of its task's page: its files (linked) with their provenance, every configuration with
    the grid figure, the paper's settings against the grid, the loss analysis (the paper's Table 3), and the copycat
    diagnostics."""
    m = ctx.merged[key]
    aside = {}
    for where, method in m.set_aside:
        aside.setdefault(where, []).append(method)
    body = [*(f"- [`{pathlib.Path(r.path).name}`]({ctx.link(r.path)}): {provenance(r)}"
              + (f" Its {', '.join(aside[r.path])}, trained for another of its methods to read, is left out of the "
                 "tables: another file of this group trained the same configuration as a row of its own."
                 if r.path in aside else "") for r in m.sources), "",
            grid_table(m), *retrained_line(m),
            *ctx.figure(f"grid-{file_stem(m)}.png", f"{m.title} grid search", lambda: figures.grid_figure(m))]
    if max((r["n_seeds"] for r in m.summary), default=0) < 2:
        if choices(m):  # no std to judge a gap by, and no best among settings of one seed each
            body += ["The paper's settings against the best of our grid: not judged at 1 seed (no std over seeds; "
                     "--seeds 3 or more for one).", ""]
    elif found := choices_table(m):
        body += ["The paper's settings against the best of our grid (\"within one std\": the gap at most the larger "
                 "std over seeds).", "", found]
    body += ["Loss analysis (the paper's Table 3): mean per-sample loss; changepoints the top 10% APE.", "",
             loss_table(m)]
    if copycat := copycat_table(m):
        body += ["The evaluation rollouts: ψ's APE of each policy's own actions and its error against the expert's "
                 "action on its own states.", "", copycat]
    return [Section(group_title(m), body=body + group_diagnostics(m) + training_table(m))]
