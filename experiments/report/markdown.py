"""The report's markdown: every table, each file's provenance, and `build` (the whole section and its figures).

The numbers come from `experiments.report.analysis`, the figures from
`experiments.report.figures`; this module formats, and draws nothing itself
(`build` asks the figure builders for the figures it links).
"""

from __future__ import annotations

import math
import os
import pathlib
import shlex

import numpy as np

from ape_jax import methods as methods_lib
from ape_jax import tasks
from ape_jax.pipeline import results as results_lib
from experiments.report import figures
from experiments.report.analysis import (BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, MUJOCO, PAPER_SENSITIVITY_TAU,
                                         PAPER_SENSITIVITY_W, PAPER_TABLE5, Interval, _best, _env_title,
                                         _metric, _ordered, _paper_step, _pct, _rows, bootstrap_rows, choices,
                                         copycat_groups, envs_of, expert_ape, extra_methods, gap, headline,
                                         is_rate, known_methods, label, loss_rows, merge, sensitivity,
                                         task_metric_rows, verdict, weight_shares)

# How the task-metrics table heads a task's own metrics, and the factor it shows them at (rates in %); a metric
# not listed is headed by its name, and a task's main metric (a rate) is shown in %.
METRIC_HEADINGS = {"red_light_violations": ("red-light violations", 1.0), "avg_speed": ("average speed", 1.0),
                   "stuck": ("stuck %", 100.0)}


def _cell(row: dict | None) -> str:
    if row is None:
        return "—"
    norm = f" ({row['normalized_mean']:.0f}%)" if row.get("normalized_mean") is not None else ""
    return f"{row['return_mean']:,.0f} ± {row['return_std']:,.0f}{norm}"


def _norm_cell(row: dict | None) -> str:
    return "—" if row is None or row.get("normalized_mean") is None else f"{row['normalized_mean']:.1f}"


def state_table(merged: dict, obs: str = "pos") -> str:
    """Every method per MuJoCo task with observations `obs` ("pos": MuJoCo-State, "image": MuJoCo-Image)."""
    envs = envs_of(merged, obs)
    if not envs:
        return ""
    extras, known = extra_methods(merged), known_methods(merged)
    heads = {e: headline(merged[(e, obs)], extras, known) for e in envs}
    lines = ["| method | " + " | ".join(tasks.get(e).title for e in envs) + " |", "|---|" + "---:|" * len(envs)]
    for i, (lab, _) in enumerate(heads[envs[0]]):
        generic = lab.split(" (")[0] if lab.startswith("Ours, best") else lab
        cells = []
        for e in envs:
            lab, row = heads[e][i]
            cell = _cell(row)
            if lab.startswith("Ours, best") and row is not None:
                cell += f" <br>{lab[len(generic) + 1:]}"
            cells.append(cell)
        lines.append(f"| {generic} | " + " | ".join(cells) + " |")
    experts = [merged[(e, obs)]["expert"] for e in envs]
    lines.append("| expert (ours) | " + " | ".join("—" if x["return_mean"] is None else
                                                   f"{x['return_mean']:,.0f} ± {x['return_std'] or 0:,.0f}"
                                                   for x in experts) + " |")
    lines.append("| random policy | " + " | ".join("—" if x["random_return_mean"] is None else
                                                   f"{x['random_return_mean']:,.0f}" for x in experts) + " |")
    return "\n".join(lines) + "\n"


def _metric_heading(m: dict, metric: str) -> tuple[str, float]:
    if metric in METRIC_HEADINGS:
        return METRIC_HEADINGS[metric]
    return (f"{metric} %", 100.0) if metric == m["metric"] and is_rate(m) else (metric.replace("_", " "), 1.0)


def task_table(m: dict) -> str | None:
    """A task's own per-episode metrics (its `metrics`; the supplement's Table 4 protocol): BC-SO, BC-OH and Ours
    (THR 10%, W 5), every metric as mean ± std over seeds (of each seed's episode mean), and beside them the
    paper's main metric where the task records it (`Task.paper`). None for a task without metrics."""
    metrics = m["task_metrics"]
    rows = task_metric_rows(m)
    if not metrics or not rows:
        return None
    paper = tasks.get(m["env"]).paper
    heads = [_metric_heading(m, k) for k in metrics]
    paper_head = [f"paper: {m['metric']}" + (" %" if is_rate(m) else "")] if paper else []
    lines = ["| method | seeds | " + " | ".join([name for name, _ in heads] + paper_head) + " |",
             "|---|---:|" + "---:|" * (len(heads) + len(paper_head))]
    for lab, method, runs in rows:
        cells = []
        for key, (_, scale) in zip(metrics, heads):
            v = np.array([r["eval"][key] for r in runs if key in r["eval"]], float) * scale
            cells.append(f"{v.mean():.2f} ± {v.std():.2f}" if len(v) else "—")
        if paper:
            cells.append(f"{paper[method][0]} ± {paper[method][1]}" if method in paper else "—")
        lines.append(f"| {lab} | {len(runs)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def paper_table(merged: dict) -> str:
    """Ours next to the supplement's Table 5, each method as a ratio to BC-OH within its own source."""
    envs = envs_of(merged, "pos")
    if not envs:
        return ""
    known = known_methods(merged)
    lines = ["| method | " + " | ".join(f"{tasks.get(e).title}: paper | {tasks.get(e).title}: ours" for e in envs)
             + " |", "|---|" + "---:|" * (2 * len(envs))]
    ours = {e: {"bc-so": _best(_rows(merged[(e, "pos")], "bc-so")), "bc-oh": _best(_rows(merged[(e, "pos")], "bc-oh")),
                "fca": _best(_rows(merged[(e, "pos")], "fca")), "ours": _paper_step(merged[(e, "pos")])}
            for e in envs}
    for method in PAPER_TABLE5:
        cells = []
        for e in envs:
            paper, paper_bcoh = PAPER_TABLE5[method][e], PAPER_TABLE5["bc-oh"][e]
            row, bcoh = ours[e][method], ours[e]["bc-oh"]
            cells.append(f"{paper:,} ({paper / paper_bcoh:.2f}×)")
            cells.append("—" if row is None or bcoh is None else
                         f"{row['return_mean']:,.0f} ({row['return_mean'] / bcoh['return_mean']:.2f}×)")
        name = "Ours" if method == "ours" else label(known, method)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def grid_table(m: dict) -> str:
    """Every configuration: return and % of expert (a task judged by a rate, its reward not its measure: the rate
    in %)."""
    rows = list(m["summary"])
    best = _best([r for r in rows if r["n_seeds"]])
    rate = is_rate(m)
    heads = [f"{m['metric']} %"] if rate else ["return", "% of expert"]
    lines = ["| method | hparams | seeds | " + " | ".join(heads) + " |", "|---|---|---:|" + "---:|" * len(heads)]
    for r in rows:
        hp = ", ".join(f"{k} {v:g}" for k, v in r["hparams"].items()) or "—"
        lab = label(m["methods"], r["method"])
        ok = r["n_seeds"] and (not rate or r.get("normalized_mean") is not None)
        if not ok:
            lines.append(f"| {lab} | {hp} | {r['n_seeds']} | failed |" + ("" if rate else " |"))
            continue
        mark = "**" if r is best else ""
        if rate:
            cells = [f"{mark}{r['normalized_mean']:.1f} ± {r['normalized_std']:.1f}{mark}"]
        else:
            cells = [f"{mark}{r['return_mean']:,.1f} ± {r['return_std']:,.1f}{mark}",
                     f"{r['normalized_mean']:.1f}" if r.get("normalized_mean") is not None else "—"]
        lines.append(f"| {mark}{lab}{mark} | {hp} | {r['n_seeds']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def loss_table(m: dict) -> str:
    """The paper's Table 3: mean over seeds of the per-sample loss, all / changepoint / copycat, train / val."""
    keys = [(s, k) for s in ("train", "val") for k in ("unweighted", "changepoint", "copycat")]
    lines = ["| method | " + " | ".join(f"{s}: {'all' if k == 'unweighted' else k}" for s, k in keys) + " |",
             "|---|" + "---:|" * len(keys)]
    for lab, runs in loss_rows(m):
        vals = [sum(r["losses"][s][k] for r in runs) / len(runs) for s, k in keys]
        lines.append(f"| {lab} | " + " | ".join(f"{v:.4f}" for v in vals) + " |")
    return "\n".join(lines) + "\n"


def copycat_table(m: dict) -> str | None:
    """The copycat diagnostics of every configuration that has them (None if no run does).

    Per configuration, the mean over seeds of each seed's mean over evaluation episodes of
    `rollout_ape` (the APE of the policy's own actions, ÷ the training set's mean APE) and
    `imitation_error` (Σ_d (a − a*)² against the expert's action on the policy's own states).
    """
    groups = copycat_groups(m)
    if not groups:
        return None
    expert = expert_ape(m)
    unit = _metric(m)[1] if _metric(m)[0] == "normalized" else "% of expert"
    lines = ["| method | hparams | seeds | rollout APE (÷ training mean) | imitation error on own states | "
             f"{unit} |", "|---|---|---:|---:|---:|---:|"]
    if expert is not None:
        lines.append(f"| expert (validation demonstrations) | — | — | {expert:.2f} | 0 | "
                     f"{'—' if is_rate(m) else 100} |")
    for (method, hp), runs in groups.items():
        mean = lambda k: sum(r["eval"][k] for r in runs) / len(runs)  # noqa: E731
        norm = f"{mean('normalized'):.1f}" if all("normalized" in r["eval"] for r in runs) else "—"
        hps = ", ".join(f"{k} {v:g}" for k, v in hp) or "—"
        lines.append(f"| {label(m['methods'], method)} | {hps} | {len(runs)} | {mean('rollout_ape'):.3f} | "
                     f"{mean('imitation_error'):.4f} | {norm} |")
    return "\n".join(lines) + "\n"


def sensitivity_table(merged: dict) -> str | None:
    """The sensitivity study on Walker2d (states): τ ∈ {0.1, 0.2, 0.5} and W ∈ {4, 5, 6} at THR 10%, with the paper's."""
    m = merged.get(("walker2d", "pos"))
    if m is None:
        return None
    tau, w = sensitivity(m)
    if not any(r for _, r in tau + w):
        return None
    lines = ["| setting | ours: Walker2d return | ours: % of expert | paper |", "|---|---:|---:|---:|"]
    for t, r in tau:
        paper = f"Walker2d {PAPER_SENSITIVITY_TAU[t][0]} ± {PAPER_SENSITIVITY_TAU[t][1]}"
        lines.append(f"| softmax τ {t:g} | {_cell(r).split(' (')[0]} | {_norm_cell(r)} | {paper} |")
    for x, r in w:
        lines.append(f"| step THR 10%, W {x:g} | {_cell(r).split(' (')[0]} | {_norm_cell(r)} | "
                     f"driving {PAPER_SENSITIVITY_W[x]}% success |")
    for name, group in (("τ", tau), ("W", w)):
        got = [r for _, r in group if r is not None]
        if len(got) == len(group):
            spread = max(r["return_mean"] for r in got) - min(r["return_mean"] for r in got)
            std = max(r["return_std"] for r in got)
            word = "within" if spread <= std else "beyond"
            lines.append(f"\nOver {name}: the means span {spread:,.0f}, {word} the largest std over seeds ({std:,.0f}).")
    return "\n".join(lines) + "\n"


def bootstrap_table(rows: list[tuple[str, str, Interval, str]]) -> str:
    """The rows of `bootstrap_rows` as a table: difference of means, 95% CI, verdict."""
    lines = ["| environment | Ours | seeds (Ours / BC-OH) | Ours − BC-OH | 95% CI | verdict |",
             "|---|---|---:|---:|---:|---|"]
    lines += [f"| {env} | {lab} | {ci.n_a} / {ci.n_b} | {ci.diff:+,.0f} ({unit}) | [{ci.low:+,.0f}, {ci.high:+,.0f}] | "
              f"{verdict(ci)} |" for env, lab, ci, unit in rows]
    return "\n".join(lines) + "\n"


def weights_table(shares: list[tuple[str, list[tuple]]]) -> str:
    """The heaviest sample's and the heaviest 10%'s share of a batch's weight, per environment and setting."""
    lines = ["| environment | weighting | heaviest sample's share | heaviest 10%'s share |", "|---|---|---:|---:|"]
    for title, series in shares:
        for lab, y in series:
            lines.append(f"| {title} | {lab} | {100 * y[0]:.0f}% | {100 * y[max(1, round(0.1 * len(y))) - 1]:.0f}% |")
    return "\n".join(lines) + "\n"


def _fmt(mean: float, std: float, prefix: str) -> str:
    return f"{mean:.1f} ± {std:.1f}%" if prefix == "normalized" else f"{mean:,.0f} ± {std:,.0f}"


_SETTING = {"step": lambda hp: f"THR {_pct(hp['thr'])} W {hp['w']:g}", "softmax": lambda hp: f"τ {hp['tau']:g}"}


def paper_choices(m: dict) -> list[str]:
    """One sentence per weighting: is the paper's setting within one std over seeds of the grid's best?

    "Within one std" means the gap to the best is at most the larger of the two configurations' std over seeds.
    Where our APE was divided by its training-set mean, the softmax sentence also names the grid value
    nearest to the paper's τ carried over to that scale (the paper's τ acts on the raw APE).
    """
    prefix, _ = _metric(m)
    pts = " points" if prefix == "normalized" else ""

    def near(chosen: dict, best: dict, rows: list[dict], kind: str) -> str:
        g = gap(chosen, best, prefix)
        if g.is_best:
            return f"{_fmt(*g.chosen, prefix)}, the best of the {len(rows)} {kind} settings"
        where = (f"within one std over seeds ({g.noise:.1f}) of the best" if g.within else
                 f"more than one std over seeds ({g.noise:.1f}) below the best: not near it")
        return (f"{_fmt(*g.chosen, prefix)} vs the best, {_SETTING[kind](best['hparams'])}, {_fmt(*g.best, prefix)}: "
                f"{g.gap:.1f}{pts} lower, {where}")

    out = []
    for c in choices(m):
        text = f"{c.kind.capitalize()}, the paper's {_SETTING[c.kind](c.paper)}: " + (
            "not run" if c.chosen is None else near(c.chosen, c.best, c.rows, c.kind)) + "."
        if c.closest is not None:
            text += (f" But our τ acts on the APE divided by its training-set mean ({c.scale:.4f}) and the paper's on "
                     f"the raw APE, so its τ {c.paper['tau']:g} is about τ {c.equivalent:.1f} here (roughly: the "
                     f"paper's APE scale is not ours); the nearest grid value, τ {c.closest['hparams']['tau']:g}: "
                     f"{near(c.closest, c.best, c.rows, c.kind)}.")
        out.append(text)
    return out


def _grid_name(env: str, obs: str) -> str:
    return f"grid-{env}.png" if obs == "pos" else f"grid-{env}-{obs}.png"


def _rebuilt_command(r: results_lib.Results) -> str:
    """The sweep command of a file that does not record its own (schema 1, or a sweep run from Python)."""
    from ape_jax.pipeline.presets import PRESETS, preset_for

    cfg = r.config
    cmd = f"python -m experiments.sweep --env {r.env} --obs {r.obs} --preset {r.preset}"
    if cfg.get("methods") != list(methods_lib.default()):
        cmd += f" --methods {','.join(cfg['methods'])}"
    preset = preset_for(r.preset, r.env, r.obs) if r.preset in PRESETS else None
    for key, flag in (("iterations", "--iterations"), ("seeds", "--seeds"), ("eval_episodes", "--eval-episodes")):
        if preset is not None and cfg.get(key) != getattr(preset, key):
            cmd += f" {flag} {cfg[key]}"
    if preset is not None and "step_grid" in cfg and [list(g) for g in preset.step_grid] != cfg["step_grid"]:
        cmd += " --step-grid " + ",".join(f"{thr:g}:{w:g}" for thr, w in cfg["step_grid"])
    if preset is not None and "softmax_grid" in cfg and list(preset.softmax_grid) != cfg["softmax_grid"]:
        cmd += " --softmax-grid " + ",".join(f"{tau:g}" for tau in cfg["softmax_grid"])
    return cmd


def provenance(r: results_lib.Results) -> str:
    """The command and setting one results file came from.

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
    s, t = r.system or {}, r.timing or {}
    machine = s.get("machine") or "machine not recorded in the file"
    commit = f"`{s.get('commit')}`" + (" with uncommitted changes" if s.get("dirty") else "")
    line = (f"{cmd} — {cfg['iterations']:,} iterations, {cfg['seeds']} seeds, {cfg['eval_episodes']} evaluation "
            f"episodes; commit {commit}, jax {s.get('jax')} ({s.get('backend')}, {s.get('devices')} "
            f"device(s)), {machine}; {t.get('total_s', 0):,.0f} s in all"
            + (" (resumed after an interruption: the last process's time only)" if t.get("resumed") else ""))
    if t.get("peak_rss_mb"):
        line += f", peak resident memory {t['peak_rss_mb'] / 1024:.1f} GB"
    again = r.reevaluated
    if again and again.get("fields"):
        line += (f"; {', '.join(f'`{f}`' for f in again['fields'])} added later by `python -m experiments.evaluate` "
                 f"(commit `{again['system'].get('commit')}`, every recorded number reproduced)")
    return line


def build(files: list[results_lib.Results], figure_dir: pathlib.Path | None = None,
          base: pathlib.Path | None = None) -> tuple[str, dict[pathlib.Path, object]]:
    """The report's markdown and its figures, nothing written.

    Args:
      files: loaded results files (`experiments.report.load`).
      figure_dir: where the figures will be written; None draws none (the text says so).
      base: the folder the markdown's links are relative to (the `--out` file's); default the working folder.

    Returns:
      `(text, figures)`: the markdown, and `{path: matplotlib Figure}` to write with `experiments.report.figures.save_png`.
    """
    merged = merge(files)
    drawn: dict[pathlib.Path, object] = {}
    base = pathlib.Path.cwd() if base is None else pathlib.Path(base)

    def figure(name: str, alt: str, draw) -> list[str]:
        fig = draw() if figure_dir is not None else None
        if fig is None:
            return []
        path = pathlib.Path(figure_dir) / name
        drawn[path] = fig
        return [f"![{alt}]({pathlib.Path(os.path.relpath(path.absolute(), base.absolute())).as_posix()})", ""]

    out = []
    if any((e, "pos") in merged for e in MUJOCO):
        out += ["### MuJoCo-State (velocities removed)", "",
                "Return mean ± std over seeds (each seed's mean over the evaluation episodes), and in "
                "brackets the percentage of our expert's return, normalised against a random policy. "
                "\"Best\" rows pick the configuration with the highest return on the evaluation episodes "
                "(selection on the test episodes, as the paper's grid search does; optimistic).", "",
                state_table(merged),
                "Next to the supplement's Table 5 (its own experts, whose returns it does not give): mean "
                "returns, and in brackets each method's ratio to BC-OH of the same source.", "",
                paper_table(merged)]
    if any((e, "image") in merged for e in MUJOCO):
        out += ["### MuJoCo-Image", "",
                "As MuJoCo-State, from rendered frames (the image presets: see each file's provenance below).", "",
                state_table(merged, "image")]
    for (env, obs), m in _ordered(merged):
        table = task_table(m)
        if table:
            task = tasks.get(env)
            title = task.title if obs == task.default_obs else _env_title(env, obs)
            paper = (f"; the paper's {m['metric']} rates beside (its own {task.title}, not ours)" if task.paper
                     else "")
            out += [f"### {title} (the supplement's Table 4 protocol)", "",
                    f"{task.title}'s own metrics per policy, mean ± std over seeds of each seed's mean over "
                    f"evaluation episodes{paper}.", "", table]
    if figure_dir is None:
        out += ["_Figures not drawn: the report was printed without `--figures DIR` (with `--out` they go to "
                "`figures/` next to it)._", ""]
    boot = bootstrap_rows(merged)
    returns = figure("returns.png", "Return per method and environment", lambda: figures.returns_figure(merged))
    if boot or returns:
        out += ["### Ours vs BC-OH over seeds", ""] + returns
    if boot:
        seeds = min(min(ci.n_a, ci.n_b) for _, _, ci, _ in boot)
        rates = list(dict.fromkeys(f"{tasks.get(m['env']).title}: in {m['metric']} rate"
                                   for _, m in _ordered(merged) if is_rate(m)))
        out += ["Ours − BC-OH in mean return over seeds" + (f" ({'; '.join(rates)})" if rates else "") + ", with a "
                "95% percentile bootstrap confidence interval "
                f"(each arm's seeds resampled with replacement, independently, {BOOTSTRAP_RESAMPLES:,} times; "
                f"numpy seed {BOOTSTRAP_SEED}). The best-step and best-softmax rows were selected after the fact "
                "on these same evaluation returns, so their differences are optimistic.", "", bootstrap_table(boot),
                f"Caveat: with {seeds} seed{'s' * (seeds != 1)} per arm each arm has only "
                f"{math.comb(2 * seeds - 1, seeds)} distinct resamples, so the interval is coarse, and at so few "
                "seeds the percentile bootstrap is too narrow (it under-covers): read \"better\" as a hint, and "
                "\"not significant\" as \"these seeds cannot tell\", not as evidence of no effect.", ""]
    sens = sensitivity_table(merged)
    if sens:
        out += ["### Sensitivity (the supplement's §4)", "",
                "Walker2d (states), softmax τ and the step weight W at THR 10%, next to the paper's numbers "
                "(its W study was on CARLA driving, so only the pattern compares).", "", sens]
    shares = weight_shares(merged)
    extra = figure("curves.png", "Training curves", lambda: figures.curves_figure(merged)) + \
        figure("weights.png", "Weight concentration within a batch", lambda: figures.weights_figure(shares))
    if shares:
        extra += [weights_table(shares)]
    if extra:
        out += ["### Training curves and weights", "",
                "From the results files that record them (runs since the training curve and the APE quantiles "
                "were added to `results.json`). Weights: batches of 128 drawn from each task's training APE "
                "distribution and weighted as the sweep does, `B·softmax(APE/τ)` or the step function; each curve "
                "is the share of a batch's total weight its k heaviest samples carry (uniform weights: the "
                "diagonal). A curve near 1 at k = 1 is a batch whose loss is one sample's.", ""] + extra
    for (env, obs), m in _ordered(merged):
        out += [f"### {tasks.get(env).title}, `{obs}` observations: every configuration", ""]
        out += [f"- {provenance(r)}" for r in m["sources"]]
        out += ["", grid_table(m)]
        out += figure(_grid_name(env, obs), f"{_env_title(env, obs)} grid search", lambda: figures.grid_figure(m))
        sentences = paper_choices(m)
        if sentences:
            unit = _metric(m)[1]
            out += [f"Are the paper's settings near the best of our grid? (In {unit}; \"within one std\": "
                    "the gap to the best is at most the larger of the two settings' std over seeds.)", ""]
            out += [f"- {c}" for c in sentences] + [""]
        out += ["Loss analysis (the paper's Table 3; mean over seeds of the per-sample "
                "loss; changepoints = top 10% APE of each split):", "", loss_table(m)]
        copycat = copycat_table(m)
        if copycat:
            out += ["Copycat diagnostics, from the evaluation rollouts: how predictable each policy's own "
                    "actions are from its previous 9 (ψ's APE, ÷ the training set's mean APE; a policy that "
                    "repeats its last action scores below the expert), and how far its actions are from the "
                    "expert's on the states it visits itself:", "", copycat]
    return "\n".join(out), drawn
