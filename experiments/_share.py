"""Section 7 of `experiments.bench_train` (`--share`): the share of the float32 matmul peak, measured in the same run,
that BC-OH grids reach per recipe and grid size, in one process of every thread and as one process per core (each
pinned with `taskset`, XLA single-threaded, training its share of the models, side by side: the workers are
`python -m experiments.bench_train --share-worker RECIPE:MODELS:ITERS:REPEATS`, each printing its rate as one JSON
line).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax

from ape_jax import methods
from ape_jax.learner import make_train, stack_hparams
from ape_jax.pipeline.presets import RECIPES
from experiments._timing import machine, time_jitted
from experiments._bench_common import BATCH, _data, macs_per_sample, matmul_peak, recipe_config

SHARE_RECIPES = ("fca", "mlp", "palr")
SHARE_MODELS = (13, 32, 64)
ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"   # a pinned worker's XLA


def grid_rate(recipe: str, models: int, iters: int, repeats: int) -> dict:
    """BC-OH × `models` as one `jit(vmap(scan))` of recipe `recipe` (the `palr` recipe's batch of 1,024 runs
    `iters · 128 / 1024` iterations per call): model-updates/s (steady state), compile s, and GFLOP/s by
    6 · batch · dense weights per update."""
    cfg = recipe_config(recipe, max(10, iters * BATCH // RECIPES[recipe].batch_size))
    n, learner, data = cfg.iterations, make_train(cfg), _data()
    hps = stack_hparams([methods.get("bc-oh").hparams({}, 2e-4, 0)] * models)
    states = jax.jit(jax.vmap(learner.init, (0, 0, None)))(jax.random.split(jax.random.PRNGKey(0), models), hps,
                                                            data)
    run = jax.jit(jax.vmap(lambda s, hp, d: learner.run(s, hp, d, n)[0].params, (0, 0, None)))
    compile_s, steady, _ = time_jitted(run, states, hps, data, repeats=repeats)
    rate = models * n / steady
    return {"updates_s": rate, "compile_s": compile_s,
            "gflops": 6 * cfg.batch_size * macs_per_sample(cfg) * rate / 1e9}


def pinned_rates(recipe: str, models: int, iters: int, repeats: int, cores: int) -> dict:
    """`grid_rate` as `cores` processes side by side, each pinned to one core, single-threaded, training its share
    of the `models` (the first ones take the remainder): the sums of their rates, the largest compile time."""
    shares = [models // cores + (i < models % cores) for i in range(cores)]
    env = {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} {ONE_THREAD}".strip()}
    procs = [subprocess.Popen(["taskset", "-c", str(i), sys.executable, "-m", "experiments.bench_train",
                               "--share-worker", f"{recipe}:{m}:{iters}:{repeats}"],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i, m in enumerate(shares)]
    outs = []
    for proc in procs:
        out, err = proc.communicate()
        if proc.returncode:
            raise RuntimeError(f"a pinned worker failed: {err.strip().splitlines()[-1] if err.strip() else '?'}")
        outs.append(json.loads(out.strip().splitlines()[-1]))
    return {"updates_s": sum(o["updates_s"] for o in outs), "gflops": sum(o["gflops"] for o in outs),
            "compile_s": max(o["compile_s"] for o in outs)}


def share_table(args) -> str:
    """Section 7: the share of the matmul peak per recipe and grid size, one process and one per core."""
    cores = len(os.sched_getaffinity(0))
    peak = matmul_peak(args.repeats)
    top = max(peak.values())
    rows = []
    for recipe in SHARE_RECIPES:
        for models in SHARE_MODELS:
            one = grid_rate(recipe, models, args.iters, args.repeats)
            pinned = pinned_rates(recipe, models, args.iters, args.repeats, cores) if cores > 1 else None
            rows.append((recipe, models, one, pinned))
            print(f"{recipe} × {models}: {100 * one['gflops'] * 1e9 / top:.0f}% in one process"
                  + (f", {100 * pinned['gflops'] * 1e9 / top:.0f}% pinned" if pinned else ""), file=sys.stderr)
    cmd = f"python -m experiments.bench_train --share --iters {args.iters} --repeats {args.repeats}"

    def cell(r):
        return "–" if r is None else f"{r['updates_s']:,.0f} ({100 * r['gflops'] * 1e9 / top:.0f}%)"

    lines = ["## Share of the matmul peak", "", f"Command: `{cmd}`  ", f"Machine: {machine()}  ",
             f"Medians of {args.repeats} runs after a compiling call, all in this run. The peak: the best float32 "
             f"n×n matmul ({', '.join(f'{n}: {v / 1e9:,.1f}' for n, v in peak.items())} GFLOP/s). A grid is "
             f"BC-OH × the models as one `jit(vmap(scan))`; its FLOP/s are 6 · batch · dense weights per update. "
             f"Pinned: {cores} processes side by side, each on one core (`taskset`), XLA single-threaded, each "
             f"training its share of the models; their rates summed.", "",
             "| recipe | models | one process: model-updates/s (% of peak) | compile s | pinned, one per core: "
             "model-updates/s (% of peak) | pinned ÷ one |", "|---|---:|---:|---:|---:|---:|",
             *[f"| `{recipe}` | {models} | {cell(one)} | {one['compile_s']:.1f} | {cell(pinned)} | "
               + (f"{pinned['updates_s'] / one['updates_s']:.2f}× |" if pinned else "– |")
               for recipe, models, one, pinned in rows]]
    return "\n".join(lines) + "\n"
