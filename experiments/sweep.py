"""The main job: `python -m experiments.sweep`.

Collects (or reuses) the shipped expert's demonstrations, fits APE, trains
BC-SO, BC-OH, the paper's step and softmax weighting grids and any baselines
asked for (`--methods`) × seeds as compiled programs, evaluates every policy, and writes `results.json` (the
schema: `ape_jax.pipeline.results`), `results.csv` and the trained parameters (orbax) into
`--out`. No arguments: hopper, `pos` observations, the `mujoco-state` protocol, the `quick` preset (the budget), the
protocol's recipe (`bn-mlp`: the FCA code's BatchNorm network and optimiser).

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
import pathlib
import shlex
import shutil
import sys

from experiments import _distributed, _reference
from experiments._table import table
from experiments._cli import (EPISODES_LIMIT, UPDATES_LIMIT, Parser, add_compile_cache_flag, checked_bar,
                             data_directory, end_if_compiling, fail, interrupts, raise_if_interrupted, refused,
                             unwritable, use_compile_cache)
from experiments._sweep_checks import Cost, cost, demonstrations_writable, grid, step_setting, temperature  # noqa: F401 (Cost: read here)

PROG = "python -m experiments.sweep"


def parse(argv=None, writes: bool = True) -> argparse.Namespace:
    """The command line, checked (one line and exit status 2 for bad input); `writes=False`: --out is not probed."""
    import envs
    from ape_jax import methods, tasks
    from ape_jax.pipeline import data
    from ape_jax.pipeline import presets
    from ape_jax.weighting import SoftmaxKnobs, StepKnobs

    p = Parser(prog=PROG, description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help=f"{', '.join(tasks.sweepable())} (default: hopper)")
    p.add_argument("--obs", default=None, help="observation mode (default: the task's: pos, or image for the "
                                               "driving sandbox)")
    p.add_argument("--protocol", default=None,
                   help=f"how demonstrations and evaluation are set up: {', '.join(tasks.PROTOCOLS)} (default: the "
                        "task's: mujoco-state, the paper's frame skip 1, for state observations; brax for images)")
    p.add_argument("--preset", default="quick", choices=sorted(presets.BUDGETS),
                   help="the budget: quick: <= 5 min on a 2-core CPU; default: the CPU numbers we report; paper: "
                        "for GPUs")
    p.add_argument("--recipe", default=None,
                   help=f"how policies are built and trained: {', '.join(presets.RECIPES)} (default: bn-mlp under "
                        "the mujoco-state protocols for state observations, the FCA code's BatchNorm network, Adam "
                        "beta1 0.5, batch 64; mlp otherwise)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="sets",
                   help="change one field of the protocol, budget or recipe, or one of a method's own settings "
                        "(repeatable), e.g. recipe.batch_size=64, protocol.split=episodes, fca.alphas=0.1,0.5,1,2")
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
                        "rerun with the same --out and settings does without this flag); refused where --out holds "
                        "no sweep (an empty or mistyped folder)")
    p.add_argument("--fresh", action="store_true",
                   help="start a new sweep in --out: delete the results, policies, curves and checkpoints it holds "
                        "(if any) and start over; what to pass where --resume finds no sweep to continue")
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
    p.add_argument("--yes", action="store_true",
                   help=f"run a sweep over the cost limit ({UPDATES_LIMIT:,} model updates, i.e. configurations x "
                        f"seeds x iterations, or {EPISODES_LIMIT:,} evaluation episodes), which is refused without it")
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
        args.protocol = tasks.get(args.env).protocol(presets.current_protocol(args.protocol), args.obs).name
    except ValueError as e:
        fail(p, str(e))
    args.plugins = tuple(m.strip() for m in args.plugins.split(",") if m.strip())
    if paths := [m for m in args.plugins if "/" in m or m.endswith(".py")]:   # import_module's words would mislead
        fail(p, f"--plugins {paths[0]}: a file path; give the module's name (my_plugin for my_plugin.py, with its "
                "folder on PYTHONPATH)")
    named = {w.strip() for w in args.methods.split(",")} - set(methods.shortcuts())  # asked for by name
    try:
        methods.load_plugins(args.plugins)
        args.methods = methods.resolve(args.methods)
    except (methods.PluginError, methods.MethodError) as e:
        fail(p, str(e))
    for name in ("seeds", "iterations", "eval_episodes", "checkpoint_every"):
        value = getattr(args, name)
        if value is not None and value < 1:
            fail(p, f"--{name.replace('_', '-')} must be >= 1")
        if value is not None and value > presets.BUDGET_MAX:   # would overflow on the device after collecting
            fail(p, f"--{name.replace('_', '-')} must be at most {presets.BUDGET_MAX:,} (the device counts in "
                    f"32-bit integers), got {value:,}")
    # the shortcuts are --set's of the budget and of every step (softmax) weighting's grid, before the --set's given
    sets = [f"budget.{k}={v}" for k, v in (("seeds", args.seeds), ("iterations", args.iterations),
                                           ("eval_episodes", args.eval_episodes)) if v is not None]
    if args.step_grid is not None:
        steps = grid(p, "--step-grid", args.step_grid, step_setting)
        sets += [f"{m}.grid=" + ",".join(f"{thr!r}:{w!r}" for thr, w in steps) for m in methods.sharing(StepKnobs)]
    if args.softmax_grid is not None:
        taus = ",".join(map(repr, grid(p, "--softmax-grid", args.softmax_grid, temperature)))
        sets += [f"{m}.taus={taus}" for m in methods.sharing(SoftmaxKnobs)]
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
    # a method the shortcut brought in whose grid this preset empties (ToyTown's images: no softmax setting) is not
    # announced as trained; the header names it, so a refusal below stays one line
    args.empty = tuple(m for m in args.methods if m not in named and _empty_grid(m, args.settings))
    args.methods = _runnable(p, tuple(m for m in args.methods if m not in args.empty), named, args.settings, args.obs)
    # a method's own setting the user gave for a method the sweep will not train: nothing would read it, so it is
    # a slip (the shortcuts' and the preset's grids set every method's knobs and are not the user's: not refused)
    for item in args.sets:
        m = item.partition(".")[0].strip()
        if m in methods.names() and m not in args.methods:
            fail(p, f"--set {item}: {m} is not among --methods ({', '.join(args.methods)}), so nothing would read "
                    f"its setting: add {m} to --methods, or leave the --set out")
    args.cost = cost(args.env, args.settings, args.methods)
    if args.cost is not None and args.cost.over and not args.yes:
        fail(p, f"{args.cost}, over the limit of {UPDATES_LIMIT:,} updates or {EPISODES_LIMIT:,} episodes; pass "
                "--yes to run it anyway, or ask for fewer --seeds, --iterations or --eval-episodes")
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
        if args.resume and not holds_sweep(args.out):   # a mistyped --out would silently start afresh
            fail(p, f"--resume: {args.out} holds no sweep to resume (no results.json, no checkpoints/sweep.json); "
                    "check --out, or start a new sweep there with --fresh instead of --resume")
    args.data_dir = data_directory(p, args.data_dir)   # a file given is refused here, before --out is touched
    return args


def _runnable(p, names: tuple[str, ...], named: set[str], settings, obs: str) -> tuple[str, ...]:
    """`names` less the methods a shortcut (`all`, `baselines`, ...) brought in that cannot run under `settings`
    (`Method.refuses`: ChannelDropout without a leaking channel in view, RAP on another image encoder) or without
    a method they read (`methods.unread`: Priming without BC-SO), each left out with a line saying why; a method
    asked for by name is refused by the sweep's spec instead."""
    from ape_jax import methods

    keep = []
    for name in names:
        refuses = methods.get(name).refuses
        why = None if name in named else (refuses(settings, obs) if refuses is not None else None) \
            or methods.unread(name, settings.knobs, names)
        if why:
            print(f"{_prog()}: leaving out {name}, which the shortcut brought in: {why}", file=sys.stderr)
        else:
            keep.append(name)
    if not keep:
        fail(p, "none of the methods asked for can run under these settings (each is left out above)")
    return tuple(keep)


def _empty_grid(name: str, settings) -> str | None:
    """Why `name` has nothing to train under `settings` (its grid empty: the image presets' `softmax_grid=()`), or
    None. A plugin's grid that needs the demonstrations to be listed is not judged here."""
    from ape_jax import methods

    ctx = methods.GridContext(task=None, n_train=settings.protocol.train_transitions or 1, knobs=settings.knobs)
    try:
        return None if methods.get(name).settings(ctx) else "its grid is empty in this preset (nothing to train)"
    except Exception:  # noqa: BLE001 - a plugin's grid that reads the task or the split: the sweep lists it later
        return None


def holds_sweep(out: pathlib.Path) -> bool:
    """Whether `out` holds a sweep to resume or report: its results.json, or its checkpoints' fingerprint."""
    from ape_jax.pipeline.checkpoint import FINGERPRINT
    from ape_jax.pipeline.rundir import RunDir

    run = RunDir(out)
    return run.results.is_file() or (run.checkpoints / FINGERPRINT).is_file()


def main(argv=None) -> int:
    """The sweep from the command line; returns the exit status (0 done or reported, 2 refused, 130 Ctrl-C)."""
    state: dict = {}   # what was made, for the cleanup whatever ends the sweep
    code = None
    try:
        with interrupts():   # a Ctrl-C that lands in a gc callback still stops the sweep (`_cli.interrupts`)
            code = _main(argv, state)
        return code
    except SystemExit as e:
        code = e.code
        raise
    except KeyboardInterrupt as e:
        code = 130
        print(f"\n{_prog()}: {_interrupted(argv, state.get('args'), e)}", file=sys.stderr)
        return 130
    finally:
        if (lock := state.get("lock")) is not None:
            lock.release(restore=code == 2)   # a refusal leaves --out as it found it, a stale lock file too
        out = state["args"].out if state.get("created") else None
        if out is not None and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # a sweep refused or stopped before any work leaves no empty folder behind
        if code == 130:
            end_if_compiling(130)   # a Ctrl-C during a collection's compile: leave now, the lock released


def _main(argv, state: dict) -> int:
    procs = _distributed.start(PROG, argv)  # first: JAX's distributed runtime must start before JAX computes
    fp, opened, verdict = None, None, None
    try:
        args = state["args"] = parse(argv, writes=procs.writes)
        spec, fp = _spec(args, argv)
        if procs.writes:  # the others never look at --out
            demonstrations_writable(spec)
            state["created"] = not args.out.exists()
            state["lock"] = _hold(args.out)
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
        return _train_share(spec, procs) or procs.wait_for_writer()
    try:
        return _run(args, spec, opened)
    finally:
        procs.release()   # the others wait for it before JAX's shutdown barrier


def _prog() -> str:
    """How this command names itself (`ape-sweep` as a console script)."""
    return Parser(prog=PROG).prog


def _hold(out: pathlib.Path):
    """`out` held for this sweep (`checkpoint.OutLock`), or a refusal naming the sweep that holds it."""
    from ape_jax.pipeline.checkpoint import LockHeld, OutLock

    lock = OutLock(out)
    try:
        lock.acquire()
    except LockHeld as e:
        fail(None, str(e))
    if lock.took_over is not None:
        print(f"took over {lock.path}: the sweep that held it ({lock.took_over}) ended without releasing it")
    return lock


def _interrupted(argv, args: argparse.Namespace | None, why: BaseException | None = None) -> str:
    """The one line Ctrl-C leaves: what it stopped where that was the collection of demonstrations (`why`, a
    `collect.CollectionInterrupted`), and how to resume what was saved, or that nothing was."""
    from ape_jax.pipeline.rundir import RunDir

    collect = sys.modules.get("ape_jax.pipeline.collect")   # not imported yet: it cannot have been collecting
    if collect is not None and isinstance(why, collect.CollectionInterrupted):
        if args is None or not holds_sweep(args.out):
            return f"interrupted: {why}; run the same command again to start"
        return f"interrupted: {why}; " + _interrupted(argv, args).removeprefix("interrupted; ")
    if args is None or not holds_sweep(args.out):
        return "interrupted before anything was saved; run the same command again to start"
    given = list(sys.argv[1:] if argv is None else argv)
    given = [a for a in given if a not in ("--fresh", "--resume")]
    if not any(a == "--out" or a.startswith("--out=") for a in given):
        given += ["--out", str(args.out)]
    return (f"interrupted; {RunDir(args.out).checkpoints}/ keeps what was saved: resume with --resume and the same "
            f"--out: {shlex.join([*PROG.split(), *given, '--resume'])}")


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
        smoke = bool(old.config.get("smoke"))
        print("\n".join(_reference.reference_lines(results_path) + _reference.next_steps(args.out, smoke)))
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
        if not refused(e):
            raise
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
    if recipe.perception != "none":
        name = "the task's" if recipe.perception == "task" else pathlib.Path(recipe.perception).name
        if recipe.perception_training == "finetune":
            return f"{name} perception encoder {recipe.perception_sha256[:12]}…, fine-tuned end to end, to an mlp"
        return (f"{recipe.network} on the {recipe.perception_output} of {name} perception encoder "
                f"{recipe.perception_sha256[:12]}…, frozen")
    extras = [recipe.encoder_norm + " norm"] * (recipe.encoder_norm != "none")
    extras += [f"shift {recipe.augment_shift} px"] * (recipe.augment_shift > 0)
    return f"{recipe.encoder} encoder" + "".join(f", {x}" for x in extras)


def _run(args: argparse.Namespace, spec, checkpoint) -> int:
    """Process 0 (or the only one): the whole sweep, and every file it writes."""
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
          f"{', '.join(args.methods)}" + (f" ({', '.join(args.empty)}: no setting in this preset's grid)"
                                          if getattr(args, "empty", ()) else ""))
    if args.cost is not None and args.cost.over:
        print(f"{args.cost}, over the limit of {UPDATES_LIMIT:,} updates or {EPISODES_LIMIT:,} episodes; --yes: "
              "running it")
    if spec.settings.smoke:
        print(f"smoke run: preset {args.preset}'s settings with its amounts shrunk to seconds; it checks that the "
              f"preset runs end to end, its numbers mean nothing (the report refuses them)")
    bar = checked_bar((lambda **kw: tqdm(disable=True, **kw)) if args.quiet else
                      (lambda **kw: tqdm(dynamic_ncols=True, **kw)))   # each update: a Ctrl-C ignored stops here
    hooks = Hooks(bar=bar, log=tqdm.write, curves=lambda *a: logs.CurveLog(args.out, *a))
    try:
        res, policies = run_sweep(spec, hooks, checkpoint)
    except (ExpertError, CheckpointError, DataError, PluginError, ValueError) as e:
        checkpoint.discard_if_empty()  # a refusal leaves --out as it found it (`main` removes a folder made for it)
        if not refused(e):
            raise   # a fault inside a library (a JAX shape error): a bug, shown with its traceback
        return fail(None, str(e))
    res.system = started
    raise_if_interrupted()   # a Ctrl-C whose exception was ignored: no results written
    ckpt_lib.save_policies(out.params, policies)
    results_lib.write_csv(out.csv, res)
    results_lib.save(out.results, res)  # last: its presence means the sweep finished
    checkpoint.clear()  # the outputs hold everything now
    t = res.timing
    print()
    print(table(res))
    print(f"\ntime: {t['total_s']:.0f} s in all{' (resumed)' if t['resumed'] else ''} "
          f"(compile ~{t['compile_s']:.0f} s, train {t['train_s']:.0f} s, evaluate {t['eval_s']:.0f} s"
          + (f"; peak device memory {t['peak_device_mb'] / 1024:.1f} GB" if t.get("peak_device_mb") else "") + ")\n"
          f"wrote {out.results}, {out.csv}, {out.params}/, training curves in {out.curves}/ and {out.tensorboard}/")
    print("\n".join(_reference.reference_lines(out.results) + _reference.next_steps(args.out, spec.settings.smoke)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
