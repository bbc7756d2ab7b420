"""The main job: `python -m experiments.sweep`.

Collects (or reuses) the shipped expert's demonstrations, fits APE, trains
BC-SO, BC-OH, the paper's step and softmax weighting grids and any baselines
asked for (`--methods`) × seeds as compiled programs, evaluates every policy, and writes `results.json` (the
schema: `ape_jax.pipeline.results`), `results.csv` and the trained parameters (orbax) into
`--out`. No arguments: hopper, `pos` observations, the `fca` protocol, the `quick` preset (the budget), the
protocol's recipe (`fca`: the FCA code's BatchNorm network and optimiser).

Settings come as three records (`ape_jax.pipeline.presets`): `--protocol` (the task's setting), `--preset`
(the budget) and `--recipe` (network and optimisation); `--set SECTION.FIELD=VALUE` changes any field of
them, e.g. `--set recipe.batch_size=64 --set protocol.split=episodes`.

Interrupted sweeps resume: the training states (every configuration × seed)
are checkpointed in `OUT/checkpoints/` every `--checkpoint-every` iterations
and after each phase, and a rerun with the same `--out` and settings continues
where it stopped, bit-identically on the same machine (`ape_jax.pipeline.checkpoint`).
Rerunning a finished sweep reports it; `--fresh` discards what `--out` holds.
Per-iteration training curves go to `OUT/curves/*.csv` and TensorBoard event
files to `OUT/tensorboard/` (`ape_jax.pipeline.logs`), appended after every
chunk while the sweep trains: `tensorboard --logdir OUT/tensorboard` shows it live.

Several processes (`--coordinator HOST:PORT --num-processes N --process-id I`,
or JAX's own environment, `experiments._distributed`) train one grid sharded
over all their devices; every process prepares and trains, and process 0
alone evaluates and writes.
"""

from __future__ import annotations

import argparse
import math
import statistics
import pathlib
import shutil
import sys

from experiments import _distributed
from experiments._cli import Parser, add_compile_cache_flag, fail, unwritable, use_compile_cache

PROG = "python -m experiments.sweep"


def parse(argv=None, writes: bool = True) -> argparse.Namespace:
    """The command line, checked (one line and exit status 2 for bad input); `writes=False`: --out is not probed."""
    import envs
    from ape_jax import methods, tasks
    from ape_jax.pipeline import data
    from ape_jax.pipeline import presets

    p = Parser(prog=PROG, description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help=f"{', '.join(tasks.sweepable())} (default: hopper)")
    p.add_argument("--obs", default=None, help="observation mode (default: the task's: pos, or image for the "
                                               "driving sandbox)")
    p.add_argument("--protocol", default=None,
                   help=f"how demonstrations and evaluation are set up: {', '.join(tasks.PROTOCOLS)} (default: the "
                        "task's: fca, the paper's frame skip 1, for state observations; brax for images)")
    p.add_argument("--preset", default="quick", choices=sorted(presets.BUDGETS),
                   help="the budget: quick: <= 5 min on a 2-core CPU; default: the CPU numbers we report; paper: "
                        "for GPUs")
    p.add_argument("--recipe", default=None,
                   help=f"how policies are built and trained: {', '.join(presets.RECIPES)} (default: fca under the "
                        "fca protocols for state observations, the FCA code's BatchNorm network, Adam beta1 0.5, "
                        "batch 64; mlp otherwise)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="sets",
                   help="change one field of the protocol, budget or recipe (repeatable), e.g. "
                        "recipe.batch_size=64, protocol.split=episodes, recipe.fca_alphas=0.1,0.5,1,2")
    p.add_argument("--plugins", default="", metavar="MODULE,...",
                   help="import these modules (from PYTHONPATH) first: each registers methods with "
                        "@ape_jax.methods.weighting(NAME), which --methods can then name")
    p.add_argument("--methods", default="default",
                   help="comma list of method names, or the shortcuts all, baselines, default, plugins "
                        f"(default: {','.join(methods.default())}); built-in: {', '.join(methods.names())}")
    p.add_argument("--seeds", type=int, default=None,
                   help="seeds per configuration (default: the preset's); with --set budget.first_seed=K the seeds K, "
                        "..., K+N-1, to split a long sweep into files the report merges")
    p.add_argument("--iterations", type=int, default=None, help="training iterations (default: the preset's)")
    p.add_argument("--eval-episodes", type=int, default=None, help="evaluation episodes (default: the preset's)")
    p.add_argument("--step-grid", default=None, metavar="THR:W,...",
                   help="the step weightings' (THR, W) settings, e.g. 0.1:4,0.1:5,0.1:6 (default: the preset's, the "
                        "paper's THR 10%%/20%% x W 3/5/10)")
    p.add_argument("--softmax-grid", default=None, metavar="TAU,...",
                   help="the softmax weightings' temperatures, e.g. 0.1,0.2,0.5 (default: the preset's)")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="output directory (default: runs/sweep/ENV-OBS-PRESET, or ENV-OBS-PROTOCOL-PRESET for a "
                        "protocol other than the task's default)")
    p.add_argument("--resume", action="store_true",
                   help="continue the sweep in --out where it stopped, or report it if finished (also what a "
                        "rerun with the same --out and settings does without this flag)")
    p.add_argument("--fresh", action="store_true",
                   help="delete the results and checkpoints --out holds and start over")
    p.add_argument("--checkpoint-every", type=int, default=None,
                   help="save the training state every N iterations (default: after every chunk of the preset's, "
                        "e.g. 2,000 iterations for default)")
    p.add_argument("--dataset", default=None,
                   help="train from this dataset instead of the shipped expert's demonstrations: the project's "
                        "NAME.npz, or a Minari dataset directory or id; it must fit --env/--obs")
    p.add_argument("--smoke", action="store_true",
                   help="the preset's settings with every amount shrunk to seconds (3 short demonstration episodes, 4 "
                        "iterations, 1 seed, 2 evaluation episodes): checks that it runs end to end, e.g. --preset "
                        "paper --obs image on a CPU; its numbers mean nothing and the report refuses them")
    p.add_argument("--quiet", action="store_true", help="no progress bars (for CI logs); messages and the table only")
    p.add_argument("--data-dir", type=pathlib.Path, default=None,
                   help=f"demonstration cache (default: {data.cache_dir()})")
    _distributed.add_flags(p)
    add_compile_cache_flag(p)
    args = p.parse_args(argv)
    use_compile_cache(args)
    if args.resume and args.fresh:
        fail(p, "--resume and --fresh contradict each other")
    if args.env not in tasks.sweepable():
        fail(p, f"unknown env {args.env!r} for the sweep; valid: {', '.join(tasks.sweepable())} (envs with an expert)")
    args.obs = args.obs or tasks.get(args.env).default_obs
    if args.obs not in envs.obs_modes(args.env):
        fail(p, f"--obs {args.obs!r} is not supported by {args.env}; valid: {', '.join(envs.obs_modes(args.env))}")
    try:
        args.protocol = tasks.get(args.env).protocol(args.protocol, args.obs).name
    except ValueError as e:
        fail(p, str(e))
    args.plugins = tuple(m.strip() for m in args.plugins.split(",") if m.strip())
    try:
        methods.load_plugins(args.plugins)
        args.methods = methods.resolve(args.methods)
    except (methods.PluginError, methods.MethodError) as e:
        fail(p, str(e))
    for name in ("seeds", "iterations", "eval_episodes", "checkpoint_every"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            fail(p, f"--{name.replace('_', '-')} must be >= 1")
    # the shortcuts are --set's of the budget and the recipe, applied before the --set's given
    sets = [f"budget.{k}={v}" for k, v in (("seeds", args.seeds), ("iterations", args.iterations),
                                           ("eval_episodes", args.eval_episodes)) if v is not None]
    if args.step_grid is not None:
        grid = _grid(p, "--step-grid", args.step_grid, _step_setting)
        sets.append("recipe.step_grid=" + ",".join(f"{thr!r}:{w!r}" for thr, w in grid))
    if args.softmax_grid is not None:
        sets.append("recipe.softmax_grid=" + ",".join(map(repr, _grid(p, "--softmax-grid", args.softmax_grid,
                                                                       _temperature))))
    try:
        args.settings = presets.resolve(args.env, args.obs, args.protocol, args.preset, args.recipe, sets + args.sets,
                                        smoke=args.smoke)
        if args.checkpoint_every and args.checkpoint_every < args.settings.budget.chunk:
            # saves fall between chunks: a shorter interval makes the chunks shorter
            args.settings = presets.resolve(args.env, args.obs, args.protocol, args.preset, args.recipe,
                                            [*sets, *args.sets, f"budget.chunk={args.checkpoint_every}"],
                                            smoke=args.smoke)
    except presets.SettingsError as e:
        fail(p, str(e))
    args.checkpoint_every = args.checkpoint_every or args.settings.budget.chunk
    default_protocol = tasks.get(args.env).protocol(None, args.obs).name
    default_recipe = presets.default_recipe(tasks.PROTOCOLS[args.protocol], args.obs)
    name = [args.env, args.obs, *([args.protocol] if args.protocol != default_protocol else []),
            *([f"recipe-{args.settings.recipe.name}"] if args.settings.recipe.name != default_recipe else []),
            args.preset, *(["smoke"] if args.smoke else [])]
    args.out = args.out or pathlib.Path("runs/sweep") / "-".join(name)
    if writes:  # only process 0 touches --out (a process on another machine may not even see it)
        problem = ("exists and is not a directory" if args.out.exists() and not args.out.is_dir()
                   else unwritable(args.out))
        if problem:
            fail(p, f"--out {args.out}: {problem}")
    args.data_dir = args.data_dir or data.cache_dir()
    return args


def _grid(p, flag: str, text: str, parse_one) -> tuple:
    """A comma list of settings, each parsed by `parse_one` (ValueError -> a one-line refusal)."""
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        fail(p, f"{flag} is empty")
    try:
        values = tuple(parse_one(t) for t in items)
    except ValueError as e:
        fail(p, f"{flag}: {e}")
    if len(set(values)) != len(values):
        fail(p, f"{flag} lists a setting twice")
    return values


def _step_setting(text: str) -> tuple[float, float]:
    thr, sep, w = text.partition(":")
    if not sep:
        raise ValueError(f"{text!r} is not THR:W (e.g. 0.1:5)")
    thr, w = float(thr), float(w)
    if not 0.0 < thr < 1.0:
        raise ValueError(f"THR must be in (0, 1), got {thr:g}")
    if not 1.0 <= w < math.inf:
        raise ValueError(f"W must be a finite number >= 1, got {w:g}")
    return thr, w


def _temperature(text: str) -> float:
    tau = float(text)
    if not 0.0 < tau < math.inf:
        raise ValueError(f"tau must be a finite number > 0, got {tau:g}")
    return tau


def table(res) -> str:
    """The printed summary: one row per configuration, the task's main metric first, the best marked; where runs
    record copycat diagnostics (`ape_jax.diagnostics`), each configuration's median embedding and predictability
    ratios over seeds and its seeds judged copycat / seeds whose diagnostics could be read."""
    metric = res.main_metric
    shown = list(res.config.get("task_metrics", []))
    rows = [r for r in res.summary if r["n_seeds"]]
    best = max(rows, key=lambda r: r["normalized_mean"] if r["normalized_mean"] is not None else -math.inf,
               default=None)

    def read(runs):  # the readable diagnostics of `runs`; `{"absent": why}` is not read (shown "-", never 0)
        return [d for x in runs if isinstance(d := x.get("diagnostics"), dict) and "absent" not in d]

    def median(blocks, key):
        v = [b[key] for b in blocks if isinstance(b.get(key), (int, float)) and math.isfinite(b[key])]
        return f"{statistics.median(v):.3g}" if v else "-"

    def spread(r, key):  # the sample sd over seeds of the per-seed means (the summary keeps the population sd)
        v = [x["eval"][key] for x in res.runs if x["method"] == r["method"] and x["hparams"] == r["hparams"]
             and x["status"] == "ok" and isinstance((x.get("eval") or {}).get(key), (int, float))]
        return statistics.stdev(v) if len(v) >= 2 else None

    diagnosed = bool(read(res.runs))
    controlled = any("controlled_verdict" in b for b in read(res.runs))   # judged against its BC-SO
    heads = [f"{m} (mean ± sd over seeds)" for m in shown] if shown else ["return (mean ± sd over seeds)"]
    width = [max(len(h), 18) for h in heads]
    lines = [f"{'':2}{'method':<17}{'hparams':<30}{'seeds':>5}  " + "  ".join(f"{h:>{w}}" for h, w in zip(heads, width))
             + ("" if metric != "return" else f"  {'normalized':>11}")
             + (f"  {'emb ratio':>9}  {'pred ratio':>10}  {'copycat':>7}" if diagnosed else "")
             + (f"  {'ctl ratio':>9}  {'controlled':>10}" if controlled else "")]
    absent = []
    for r in res.summary:
        hp = ", ".join(f"{k}={v:g}" for k, v in r["hparams"].items()) or "-"
        if res.online(r["method"]):
            hp = f"{hp} (online)"
        if not r["n_seeds"]:
            lines.append(f"{'':2}{r['method']:<17}{hp:<30}{0:>5}  {'failed':>{width[0]}}")
            continue
        mark = "* " if r is best else "  "
        if shown:
            scale = {m: 100.0 if m == metric else 1.0 for m in shown}
            cells = [_pm(r["metrics"][m]["mean"], spread(r, m), scale[m], "%" if m == metric else "")
                     for m in shown]
        else:
            sd = spread(r, "return_mean")
            cells = [f"{r['return_mean']:,.1f}" + (f" ± {sd:,.1f}" if sd is not None else " (1 seed)")]
        line = (f"{mark}{r['method']:<17}{hp:<30}{r['n_seeds']:>5}  "
                + "  ".join(f"{c:>{w}}" for c, w in zip(cells, width)))
        if metric == "return":
            line += f"  {r['normalized_mean']:>10.1f}%"
        if diagnosed:
            runs = [x for x in res.runs if x["method"] == r["method"] and x["hparams"] == r["hparams"]
                    and x["status"] == "ok"]
            blocks = read(runs)
            count = f"{sum(b.get('verdict') == 'copycat' for b in blocks)}/{len(blocks)}" if blocks else "-"
            line += (f"  {median(blocks, 'embedding_ratio'):>9}  {median(blocks, 'predictability_ratio'):>10}"
                     f"  {count:>7}")
            if controlled:
                judged = [b["controlled_verdict"] for b in blocks if "controlled_verdict" in b]
                count = f"{judged.count('copycat')}/{len(judged)}" if judged else "-"
                line += f"  {median(blocks, 'control_ratio'):>9}  {count:>10}"
            why = [d["absent"] for x in runs if isinstance(d := x.get("diagnostics"), dict) and "absent" in d]
            absent += [f"no copycat diagnostics: {r['method']}" + (f" {hp}" if r["hparams"] else "")
                       + f", {why.count(w)} of {len(runs)} seeds: {w}" for w in dict.fromkeys(why)]
        lines.append(line)
    e = res.expert
    if e.get("return_mean") is not None:
        lines.append(f"expert {e['return_mean']:,.1f} ± {e['return_std']:,.1f}, random policy "
                     f"{e['random_return_mean']:,.1f}; normalized = 100 (R - R_random) / (R_expert - R_random); "
                     "* = best configuration")
    elif metric != "return":
        lines.append(f"{metric} in % of episodes; the other metrics are per-episode means; * = best {metric}")
    if diagnosed:
        t = (res.config.get("diagnostics") or {}).get("thresholds") or {}
        rule = " and ".join(f"{name} ratio <= " + (f"{t[key]:g}" if isinstance(t.get(key), (int, float)) else
                                                   "(threshold not recorded)")
                            for name, key in (("embedding", "embedding_ratio"),
                                              ("predictability", "predictability_ratio")))
        lines += [f"copycat = {rule} (both, per seed; fixed before any result)",
                  "emb / pred ratio: medians over seeds; copycat: seeds judged copycat / seeds with diagnostics"]
        if controlled:
            c = t.get("control_ratio")
            lines.append("controlled = a policy that sees a past with ctl ratio <= "
                         + (f"{c:g}" if isinstance(c, (int, float)) else "(threshold not recorded)")
                         + " and pred ratio <= " + (f"{t['predictability_ratio']:g}" if isinstance(
                             t.get("predictability_ratio"), (int, float)) else "(threshold not recorded)")
                         + "; ctl ratio: the embedding's error on a_t-1 / the median of bc-so's (no history, the "
                         "same rows and probe)")
    lines += absent
    for r in res.runs:
        if r["status"] != "ok":
            lines.append(f"failed: {r['method']} {r['hparams']} seed {r['seed']}: {r['error']}")
    return "\n".join(lines)


def _pm(mean, sd, scale: float, unit: str) -> str:
    """`mean ± sd` as a cell (`sd` None: one seed, no spread to show)."""
    if mean is None:
        return "-"
    digits = 1 if scale != 1 else 2
    cell = f"{scale * mean:,.{digits}f}{unit}"
    return cell + (f" ± {scale * sd:,.{digits}f}{unit}" if sd is not None else " (1 seed)")


def main(argv=None) -> int:
    procs = _distributed.start(PROG, argv)  # first: JAX's distributed runtime must start before JAX computes
    fp, opened, verdict = None, None, None
    try:
        args = parse(argv, writes=procs.writes)
        spec, fp = _spec(args, argv)
        created = procs.writes and not args.out.exists()
        if procs.writes:  # the others never look at --out
            opened = _open_out(args, fp)
            verdict = opened if isinstance(opened, int) else None
    except SystemExit as e:
        if procs.count == 1:
            raise
        verdict = e.code if isinstance(e.code, int) else 0 if e.code is None else 2
    # a refusal on any process, or a finished sweep, stops them all before any trains (the others would wait for it)
    code = procs.agree(verdict, fp)
    if code is not None:
        return code
    if not procs.writes:
        return _train_share(spec, procs)
    return _run(args, spec, opened, created)


def _spec(args: argparse.Namespace, argv) -> tuple:
    """The sweep's `SweepSpec` and its fingerprint (one line and exit status 2 if its expert or settings are
    refused)."""
    from ape_jax.pipeline.sweep import SweepSpec
    from envs.experts import ExpertError

    try:
        spec = SweepSpec(args.env, args.obs, args.settings, args.methods, dataset=args.dataset, data_dir=args.data_dir,
                         command=("python", "-m", "experiments.sweep", *(sys.argv[1:] if argv is None else argv)))
        fp = spec.fingerprint()
    except (ExpertError, ValueError) as e:
        fail(None, str(e))
    return spec, fp


def _open_out(args: argparse.Namespace, fp: dict):
    """--out made ready: its opened `SweepCheckpoint`, or exit status 0 when it holds this sweep finished
    (reported). Refuses (exit 2) a finished sweep of other settings and a checkpoint it cannot resume."""
    from ape_jax.pipeline import results as results_lib
    from ape_jax.pipeline.checkpoint import CheckpointError, SweepCheckpoint, differences
    from ape_jax.pipeline.rundir import RunDir

    out = RunDir(args.out)
    results_path = out.results
    if args.fresh:
        for path in out.sweep_outputs:
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
    elif results_path.exists():
        try:
            old = results_lib.load(results_path)
            diff = differences(old.fingerprint(), fp)
        except results_lib.ResultsError as e:
            fail(None, f"{e}; move it away, or pass --fresh to replace it")
        if diff:
            fail(None, f"{args.out} holds a finished sweep with other settings, differing in "
                       f"{'; '.join(diff[:4])}; use another --out, or pass --fresh to replace it")
        print(f"{results_path} already holds this sweep; not rerunning (--fresh to train it again).\n")
        print(table(old))
        return 0
    checkpoint = SweepCheckpoint(out.checkpoints, fp, args.checkpoint_every)
    try:
        if checkpoint.open():
            print(f"resuming from {checkpoint.directory}")
    except CheckpointError as e:
        fail(None, str(e))
    return checkpoint


def _train_share(spec, procs: _distributed.Processes) -> int:
    """A process other than process 0: prepares and trains (the grid's programs need every process), writes nothing."""
    from ape_jax.pipeline.checkpoint import CheckpointError
    from ape_jax.pipeline.data import DataError
    from ape_jax.pipeline.sweep import Hooks, train_sweep
    from ape_jax.methods import PluginError
    from envs.experts import ExpertError

    try:
        train_sweep(spec, Hooks(log=lambda message: None))
    except (ExpertError, CheckpointError, DataError, PluginError, ValueError) as e:  # as process 0 refuses them
        return fail(None, f"process {procs.index}: {e}")
    print(f"process {procs.index} of {procs.count}: trained its share of the grid; process 0 evaluates and writes "
          "the results")
    return 0


def _seed_words(budget) -> str:
    """`"3 seed(s)"`, or `"seeds 4-7"` for a sweep that starts past seed 0."""
    if not budget.first_seed:
        return f"{budget.seeds} seed(s)"
    return f"seed {budget.first_seed}" if budget.seeds == 1 else \
        f"seeds {budget.first_seed}-{budget.first_seed + budget.seeds - 1}"


def _network(recipe, obs: str) -> str:
    """The policy network the run line names: the state network, or the image encoder with its settings."""
    if obs != "image":
        return recipe.network
    extras = [recipe.encoder_norm + " norm"] * (recipe.encoder_norm != "none")
    extras += [f"shift {recipe.augment_shift} px"] * (recipe.augment_shift > 0)
    return f"{recipe.encoder} encoder" + "".join(f", {x}" for x in extras)


def _run(args: argparse.Namespace, spec, checkpoint, created: bool) -> int:
    """Process 0 (or the only one): the whole sweep, and every file it writes (`created`: --out was made for it)."""
    from tqdm import tqdm

    from ape_jax.pipeline import checkpoint as ckpt_lib
    from ape_jax.pipeline import logs
    from ape_jax.pipeline import results as results_lib
    from ape_jax.pipeline.checkpoint import CheckpointError
    from ape_jax.pipeline.data import DataError
    from ape_jax.pipeline.rundir import RunDir
    from ape_jax.pipeline.sweep import Hooks, run_sweep
    from ape_jax.methods import PluginError
    from envs.experts import ExpertError
    from experiments._provenance import system

    b, r = spec.budget, spec.recipe
    started = system()  # at the start: the code that runs, not what is checked out when it ends
    out = RunDir(args.out)
    proto = spec.protocol_settings()
    print(f"sweep: {args.env} ({args.obs}), protocol {spec.protocol.name} (frame skip {proto['frame_skip'] or '-'}, "
          f"{proto['episode_length']:,}-step episodes, split by {spec.protocol.split}), preset {args.preset}: "
          f"{b.iterations:,} iterations, {_seed_words(b)}, {b.eval_episodes} evaluation episodes; recipe {r.name} "
          f"({_network(r, args.obs)}, Adam {r.lr:g} β1 {r.beta1:g}, batch {r.batch_size}); methods "
          f"{', '.join(args.methods)}")
    if spec.settings.smoke:
        print(f"smoke run: preset {args.preset}'s settings with its amounts shrunk to seconds; it checks that the "
              f"preset runs end to end, its numbers mean nothing (the report refuses them)")
    bar = (lambda **kw: tqdm(disable=True, **kw)) if args.quiet else (lambda **kw: tqdm(dynamic_ncols=True, **kw))
    hooks = Hooks(bar=bar, log=tqdm.write, curves=lambda *a: logs.CurveLog(args.out, *a))
    try:
        res, policies = run_sweep(spec, hooks, checkpoint)
    except (ExpertError, CheckpointError, DataError, PluginError, ValueError) as e:
        checkpoint.discard_if_empty()  # a refusal leaves --out as it found it
        if created and args.out.is_dir() and not any(args.out.iterdir()):
            args.out.rmdir()
        return fail(None, str(e))
    res.system = started
    ckpt_lib.save_policies(out.params, policies)
    results_lib.write_csv(out.csv, res)
    results_lib.save(out.results, res)  # last: its presence means the sweep finished
    checkpoint.clear()  # the outputs hold everything now
    t = res.timing
    print()
    print(table(res))
    print(f"\ntime: {t['total_s']:.0f} s in all{' (resumed)' if t['resumed'] else ''} "
          f"(compile ~{t['compile_s']:.0f} s, train {t['train_s']:.0f} s, evaluate {t['eval_s']:.0f} s)\n"
          f"wrote {out.results}, {out.csv}, {out.params}/, training curves in {out.curves}/ and {out.tensorboard}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
