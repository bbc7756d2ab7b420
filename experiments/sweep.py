"""The main job: `python -m experiments.sweep`.

Collects (or reuses) the shipped expert's demonstrations, fits APE, trains
BC-SO, BC-OH, the paper's step and softmax weighting grids and any baselines
asked for (`--methods`) × seeds as compiled programs, evaluates every policy, and writes `results.json` (the
schema in `DESIGN.md`), `results.csv` and the trained parameters (orbax) into
`--out`. No arguments: hopper, `pos` observations, the `quick` preset.

Interrupted sweeps resume: the training states (every configuration × seed)
are checkpointed in `OUT/checkpoints/` every `--checkpoint-every` iterations
and after each phase, and a rerun with the same `--out` and settings continues
where it stopped, bit-identically on the same machine (`ape_jax.pipeline.checkpoint`).
Rerunning a finished sweep reports it; `--fresh` discards what `--out` holds.
Per-iteration training curves go to `OUT/curves/*.csv` and TensorBoard event
files to `OUT/tensorboard/` (`ape_jax.pipeline.logs`).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import json
import math
import pathlib
import shutil
import sys

from experiments._cli import Parser, fail, unwritable

DEFAULT_METHODS = ("bc-so", "bc-oh", "ours-step", "ours-softmax")


def parse(argv=None) -> argparse.Namespace:
    import envs
    from ape_jax.pipeline import data
    from ape_jax.pipeline.sweep import METHODS, PRESETS, preset_for

    p = Parser(prog="python -m experiments.sweep", description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help="hopper, halfcheetah, walker2d or toycar (default: hopper)")
    p.add_argument("--obs", default=None, help="observation mode (default: pos; image for toycar)")
    p.add_argument("--preset", default="quick", choices=sorted(PRESETS),
                   help="quick: <= 5 min on a 2-core CPU; default: the CPU numbers we report; paper: for GPUs")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                   help=f"comma list of {', '.join(METHODS)}, or 'all', or 'baselines' "
                        f"(default: {','.join(DEFAULT_METHODS)})")
    p.add_argument("--seeds", type=int, default=None, help="seeds per configuration (default: the preset's)")
    p.add_argument("--iterations", type=int, default=None, help="training iterations (default: the preset's)")
    p.add_argument("--eval-episodes", type=int, default=None, help="evaluation episodes (default: the preset's)")
    p.add_argument("--step-grid", default=None, metavar="THR:W,...",
                   help="ours-step's (THR, W) settings, e.g. 0.1:4,0.1:5,0.1:6 (default: the preset's, the paper's "
                        "THR 10%%/20%% x W 3/5/10)")
    p.add_argument("--softmax-grid", default=None, metavar="TAU,...",
                   help="ours-softmax's temperatures, e.g. 0.1,0.2,0.5 (default: the preset's)")
    p.add_argument("--out", type=pathlib.Path, default=None, help="output directory (default: runs/sweep/ENV-OBS-PRESET)")
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
    p.add_argument("--quiet", action="store_true", help="no progress bars (for CI logs); messages and the table only")
    p.add_argument("--data-dir", type=pathlib.Path, default=None, help=f"demonstration cache (default: {data.cache_dir()})")
    args = p.parse_args(argv)
    if args.resume and args.fresh:
        fail(p, "--resume and --fresh contradict each other")
    valid_envs = [*envs.MUJOCO_TASKS, "toycar"]
    if args.env not in valid_envs:
        fail(p, f"unknown env {args.env!r} for the sweep; valid: {', '.join(valid_envs)} (envs with an expert)")
    args.obs = args.obs or ("image" if args.env == "toycar" else "pos")
    if args.obs not in envs.obs_modes(args.env):
        fail(p, f"--obs {args.obs!r} is not supported by {args.env}; valid: {', '.join(envs.obs_modes(args.env))}")
    shortcuts = {"all": METHODS, "baselines": tuple(m for m in METHODS if m not in DEFAULT_METHODS)}
    args.methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    args.methods = tuple(m for name in args.methods for m in shortcuts.get(name, (name,)))
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown or not args.methods:
        fail(p, f"unknown method(s) {unknown or args.methods!r}; valid: {', '.join(METHODS)}")
    if len(set(args.methods)) != len(args.methods):
        fail(p, "--methods lists a method twice")
    for name in ("seeds", "iterations", "eval_episodes", "checkpoint_every"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            fail(p, f"--{name.replace('_', '-')} must be >= 1")
    overrides = {k: v for k, v in (("seeds", args.seeds), ("iterations", args.iterations),
                                   ("eval_episodes", args.eval_episodes)) if v is not None}
    if args.step_grid is not None:
        overrides["step_grid"] = _grid(p, "--step-grid", args.step_grid, _step_setting)
    if args.softmax_grid is not None:
        overrides["softmax_grid"] = _grid(p, "--softmax-grid", args.softmax_grid, _temperature)
    if args.env == "toycar":
        from ape_jax.pipeline.collect import default_episodes

        overrides["episodes"] = default_episodes("toycar")
    args.preset_cfg = dataclasses.replace(preset_for(args.preset, args.env, args.obs), **overrides)
    args.out = args.out or pathlib.Path("runs/sweep") / f"{args.env}-{args.obs}-{args.preset}"
    problem = "exists and is not a directory" if args.out.exists() and not args.out.is_dir() else unwritable(args.out)
    if problem:
        fail(p, f"--out {args.out}: {problem}")
    if args.checkpoint_every:  # saves fall between chunks: a shorter interval makes the chunks shorter
        args.preset_cfg = dataclasses.replace(args.preset_cfg, chunk=min(args.preset_cfg.chunk, args.checkpoint_every))
    args.checkpoint_every = args.checkpoint_every or args.preset_cfg.chunk
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


def write_json_atomic(path: pathlib.Path, obj) -> None:
    from ape_jax.pipeline.data import write_atomic

    write_atomic(path, lambda f: f.write((json.dumps(obj, indent=2, allow_nan=False) + "\n").encode()))


def write_outputs(out: pathlib.Path, results: dict, params: dict) -> None:
    import jax
    import numpy as np
    import orbax.checkpoint as ocp

    from ape_jax.pipeline.data import write_atomic

    # orbax saves asynchronously (to a temporary name, renamed when done), so `params/` may not exist
    # yet when the JSON beside the first checkpoint is written: create it first.
    (out / "params").mkdir(parents=True, exist_ok=True)
    with ocp.StandardCheckpointer() as ckpt:
        for name, block in params.items():
            target = (out / "params" / name).absolute()
            if target.exists():
                shutil.rmtree(target)
            tree = {k: v for k, v in block.items() if k != "runs" and v is not None}
            ckpt.save(target, jax.tree.map(np.asarray, tree))
            write_json_atomic(out / "params" / f"{name}.json", block["runs"])
    rows = io.StringIO()
    w = csv.writer(rows)
    w.writerow(["method", "hparams", "n_seeds", "return_mean", "return_std", "normalized_mean", "normalized_std"])
    for row in results["summary"]:
        w.writerow([row["method"], json.dumps(row["hparams"], sort_keys=True), row["n_seeds"], row["return_mean"],
                    row["return_std"], row["normalized_mean"], row["normalized_std"]])
    write_atomic(out / "results.csv", lambda f: f.write(rows.getvalue().encode()))
    write_json_atomic(out / "results.json", results)  # last: its presence means the sweep finished


def table(results: dict) -> str:
    from ape_jax.pipeline.sweep import ONLINE

    rows = [r for r in results["summary"] if r["n_seeds"]]
    best = max(rows, key=lambda r: r["normalized_mean"], default=None)
    lines = [f"{'':2}{'method':<17}{'hparams':<30}{'seeds':>5}  {'return (mean ± std over seeds)':>32}  {'normalized':>11}"]
    for r in results["summary"]:
        hp = ", ".join(f"{k}={v:g}" for k, v in r["hparams"].items()) or "-"
        if not r["n_seeds"]:
            lines.append(f"{'':2}{r['method']:<17}{hp:<30}{0:>5}  {'failed':>32}")
            continue
        mark = "* " if r is best else "  "
        if r["method"] in ONLINE:
            hp = f"{hp} (online)"
        ret = f"{r['return_mean']:,.1f} ± {r['return_std']:,.1f}"
        lines.append(f"{mark}{r['method']:<17}{hp:<30}{r['n_seeds']:>5}  {ret:>32}  {r['normalized_mean']:>10.1f}%")
    e = results["expert"]
    if e["return_mean"] is not None:
        lines.append(f"expert {e['return_mean']:,.1f} ± {e['return_std']:,.1f}, random policy "
                     f"{e['random_return_mean']:,.1f}; normalized = 100 (R - R_random) / (R_expert - R_random); "
                     "* = best configuration")
    failed = [r for r in results["runs"] if r["status"] != "ok"]
    for r in failed:
        lines.append(f"failed: {r['method']} {r['hparams']} seed {r['seed']}: {r['error']}")
    return "\n".join(lines)


OUTPUTS = ("results.json", "results.csv", "params", "curves", "tensorboard", "checkpoints")


def main(argv=None) -> int:
    args = parse(argv)
    from tqdm import tqdm

    from ape_jax.pipeline import logs
    from ape_jax.pipeline.checkpoint import CheckpointError, SweepCheckpoint, differences
    from ape_jax.pipeline.data import DataError
    from ape_jax.pipeline.sweep import data_settings, fingerprint, results_fingerprint, run_sweep
    from envs.experts import ExpertError

    p = args.preset_cfg
    try:
        fp = fingerprint(args.env, args.obs, args.preset, p, args.methods,
                         data_settings(args.env, args.obs, p, args.dataset))
    except (ExpertError, ValueError) as e:
        return fail(None, str(e))
    results_path = args.out / "results.json"
    if args.fresh:
        for name in OUTPUTS:
            path = args.out / name
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
    elif results_path.exists():
        try:
            old = json.loads(results_path.read_text())
            diff = differences(results_fingerprint(old), fp)
        except (OSError, ValueError, AttributeError) as e:
            return fail(None, f"{results_path} is unreadable ({e}); move it away, or pass --fresh to replace it")
        if diff:
            return fail(None, f"{args.out} holds a finished sweep with other settings, differing in "
                              f"{'; '.join(diff[:4])}; use another --out, or pass --fresh to replace it")
        print(f"{results_path} already holds this sweep; not rerunning (--fresh to train it again).\n")
        print(table(old))
        return 0
    created = not args.out.exists()
    checkpoint = SweepCheckpoint(args.out / "checkpoints", fp, args.checkpoint_every)
    try:
        if checkpoint.open():
            print(f"resuming from {checkpoint.directory}")
    except CheckpointError as e:
        return fail(None, str(e))

    print(f"sweep: {args.env} ({args.obs}), preset {args.preset}: {p.iterations:,} iterations, {p.seeds} seed(s), "
          f"{p.eval_episodes} evaluation episodes, methods {', '.join(args.methods)}")
    bar = (lambda **kw: tqdm(disable=True, **kw)) if args.quiet else (lambda **kw: tqdm(dynamic_ncols=True, **kw))
    try:
        results, params = run_sweep(args.env, args.obs, args.preset, p, args.methods, args.data_dir,
                                    bar=bar, log=tqdm.write, checkpoint=checkpoint, dataset=args.dataset,
                                    curves=lambda *a: logs.write_curves(args.out, *a))
    except (ExpertError, CheckpointError, DataError, ValueError) as e:
        checkpoint.discard_if_empty()  # a refusal leaves --out as it found it
        if created and args.out.is_dir() and not any(args.out.iterdir()):
            args.out.rmdir()
        return fail(None, str(e))
    write_outputs(args.out, results, params)
    checkpoint.clear()  # the outputs hold everything now
    t = results["timing"]
    print()
    print(table(results))
    print(f"\ntime: {t['total_s']:.0f} s in all{' (resumed)' if t['resumed'] else ''} (compile ~{t['compile_s']:.0f} s, "
          f"train {t['train_s']:.0f} s, evaluate {t['eval_s']:.0f} s)\n"
          f"wrote {results_path}, {args.out / 'results.csv'}, {args.out / 'params'}/, training curves in "
          f"{args.out / 'curves'}/ and {args.out / 'tensorboard'}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
