"""Section 7 of `experiments.bench_train` (`--share`): the share of the float32 matmul peak, measured in the same run,
that BC-OH grids reach per recipe and grid size, in one process of every thread and as one process per core (each
pinned with `taskset`, XLA single-threaded, training its share of the models, side by side: the workers are
`python -m experiments.bench_train --share-worker RECIPE:MODELS:ITERS:REPEATS`, each printing its rate as one JSON
line).

Where the time goes (`profile_rates`, one pinned single-threaded worker): the recipe's layer shapes as plain code
built up stage by stage, the products alone, then BatchNorm, then Adam, beside the learner's own step, for one model
and for one core's share of a grid, against that core's own matmul peak. A stage's cost is its rate's drop.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import optax

from ape_jax import methods
from ape_jax.learner import make_train, stack_hparams
from ape_jax.models import Head
from ape_jax.pipeline.presets import RECIPES
from experiments._timing import machine, time_jitted
from experiments._bench_common import BATCH, OBS, H, _data, macs_per_sample, matmul_peak, recipe_config

SHARE_RECIPES = ("bn-mlp", "mlp", "mlp-b1024")
SHARE_MODELS = (13, 32, 64)
ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"   # a pinned worker's XLA


def grid_rate(recipe: str, models: int, iters: int, repeats: int) -> dict:
    """BC-OH × `models` as one `jit(vmap(scan))` of recipe `recipe` (the `mlp-b1024` recipe's batch of 1,024 runs
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


PROFILE_STAGES = ("products", "batchnorm", "adam")   # what each stage adds to the one before it
PROFILE_MODELS = (1, 16)                             # one model; one core's share of a 32-model grid


def layer_widths(cfg) -> list[int]:
    """The widths of a state recipe's dense chain, input first (`StatePolicy`: encoder, embedding, head,
    action); checked against the network's own dense weights."""
    model = cfg.model()
    widths = [H * OBS, *model.hidden, Head.embed, Head.hidden, cfg.action_dim]
    if sum(a * b for a, b in zip(widths, widths[1:])) != macs_per_sample(cfg):
        raise RuntimeError(f"the profile's chain {widths} is not recipe {cfg.network}'s network")
    return widths


def stage_rate(recipe: str, models: int, iters: int, repeats: int, stage: str) -> float:
    """Model-updates/s of `models` copies of the recipe's dense chain (`layer_widths`, the recipe's batch drawn
    from the benchmark's data each step, LeakyReLU(0.2), squared error) as one `jit(scan(vmap))`, built up to
    `stage`: `products` (forward and backward products, an SGD step), `batchnorm` (each encoder layer normalised
    by the batch's statistics, as the recipe's network does in training) or `adam` (optax's Adam moments with the
    recipe's β1 in place of SGD)."""
    cfg = recipe_config(recipe, iters)
    widths, batch, data = layer_widths(cfg), cfg.batch_size, _data()
    norm = stage != "products" and cfg.network == "bn-mlp"
    n_norm = len(cfg.model().hidden)
    adam = optax.scale_by_adam(b1=cfg.beta1) if stage == "adam" else None
    x_all = jnp.concatenate([data.obs, data.obs], axis=1)   # the history's width: H × OBS

    def loss(ws, x, y):
        for i, w in enumerate(ws):
            x = x @ w
            if norm and i < n_norm:
                x = (x - x.mean(0)) / jnp.sqrt(x.var(0) + 1e-5)
            x = jnp.where(x > 0, x, 0.2 * x) if i < len(ws) - 1 else x
        return jnp.mean((x - y) ** 2)

    def step(ws, opt, key):
        idx = jax.random.randint(key, (batch,), 0, x_all.shape[0])
        grads = jax.grad(loss)(ws, x_all[idx], data.action[idx])
        if adam is None:
            return [w - 1e-4 * g for w, g in zip(ws, grads)], opt
        updates, opt = adam.update(grads, opt)
        return [w - 1e-4 * u for w, u in zip(ws, updates)], opt

    keys = jax.random.split(jax.random.PRNGKey(0), models)
    ws = [jax.vmap(lambda k, i=i, a=a, b=b: jax.random.normal(jax.random.fold_in(k, i), (a, b)) / a ** 0.5)(keys)
          for i, (a, b) in enumerate(zip(widths, widths[1:]))]
    opt = jax.vmap(adam.init)(ws) if adam else None

    def run(ws, opt):
        def body(carry, t):
            return jax.vmap(step)(*carry, jax.vmap(lambda k: jax.random.fold_in(k, t))(keys)), None
        return jax.lax.scan(body, (ws, opt), jnp.arange(iters))[0][0]

    _, steady, _ = time_jitted(jax.jit(run), ws, opt, repeats=repeats)
    return models * iters / steady


def profile_rates(recipe: str, iters: int, repeats: int) -> dict:
    """Where one core's time goes (run pinned and single-threaded): this core's matmul peak (FLOP/s, the best n×n
    product) and, per `PROFILE_MODELS` count, each `PROFILE_STAGES` stage's rate and the learner's own
    (`grid_rate`), in model-updates/s."""
    out = {"peak": max(matmul_peak(repeats).values())}
    norm = recipe_config(recipe, 10).network == "bn-mlp"
    for models in PROFILE_MODELS:
        rates = {stage: stage_rate(recipe, models, iters, repeats, stage) if norm or stage != "batchnorm" else None
                 for stage in PROFILE_STAGES}   # a network without BatchNorm: nothing to add at that stage
        out[str(models)] = {**rates, "learner": grid_rate(recipe, models, iters, repeats)["updates_s"]}
    return out


def pinned_worker(spec: str, core: int) -> subprocess.Popen:
    """`python -m experiments.bench_train --share-worker SPEC`, started pinned to `core`, XLA single-threaded."""
    env = {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} {ONE_THREAD}".strip()}
    return subprocess.Popen(["taskset", "-c", str(core), sys.executable, "-m", "experiments.bench_train",
                             "--share-worker", spec], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def worker_output(proc: subprocess.Popen) -> dict:
    """A pinned worker's JSON line, once it ends."""
    out, err = proc.communicate()
    if proc.returncode:
        raise RuntimeError(f"a pinned worker failed: {err.strip().splitlines()[-1] if err.strip() else '?'}")
    return json.loads(out.strip().splitlines()[-1])


def pinned_rates(recipe: str, models: int, iters: int, repeats: int, cores: int) -> dict:
    """`grid_rate` as `cores` processes side by side, each pinned to one core, single-threaded, training its share
    of the `models` (the first ones take the remainder): the sums of their rates, the largest compile time."""
    shares = [models // cores + (i < models % cores) for i in range(cores)]
    procs = [pinned_worker(f"{recipe}:{m}:{iters}:{repeats}", i) for i, m in enumerate(shares)]
    outs = [worker_output(proc) for proc in procs]
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
    return "\n".join(lines + ["", *profile_section(args)]) + "\n"


def profile_section(args) -> list[str]:
    """Where one core's time goes, per state recipe (`profile_rates` in one pinned worker, the other cores idle)."""
    stages = ("products", "batchnorm", "adam", "learner")
    names = ("dense products (forward, backward, SGD)", "+ BatchNorm", "+ Adam", "the learner's step")
    rows, costs = [], []
    for recipe in ("bn-mlp", "mlp"):
        prof = worker_output(pinned_worker(f"profile:{recipe}:{args.iters}:{args.repeats}", 0))
        macs, batch = macs_per_sample(recipe_config(recipe, 10)), RECIPES[recipe].batch_size
        share = lambda rate: 100 * 6 * batch * macs * rate / prof["peak"]  # noqa: E731
        for models in PROFILE_MODELS:
            r = prof[str(models)]
            rows.append(f"| `{recipe}` | {models} | " + " | ".join(
                "–" if r[k] is None else f"{r[k]:,.0f} ({share(r[k]):.0f}%)" for k in stages) + " |")
            chain, before_adam = 1 / r["adam"], r["batchnorm"] or r["products"]
            norm = "" if r["batchnorm"] is None else \
                f"BatchNorm {100 * (1 / r['batchnorm'] - 1 / r['products']) / chain:.0f}%, "
            costs.append(f"`{recipe}` × {models}: the products {100 / r['products'] / chain:.0f}%, {norm}Adam "
                         f"{100 * (1 / r['adam'] - 1 / before_adam) / chain:.0f}% (the learner's own step: "
                         f"{r['adam'] / r['learner']:.2f}× the chain's time)")
    return ["### Where the time goes: one core", "",
            "One process pinned to one core, XLA single-threaded, the other cores idle; the share is of this core's "
            "own float32 matmul peak, measured in the same process. The recipe's dense chain (its layer widths and "
            "batch, drawn from the benchmark's data each step) as plain code, built up stage by stage, beside the "
            "learner's own BC-OH step; model-updates/s (% of the core's peak). 16 models: one core's share of a "
            "32-model grid run one process per core.", "",
            "| recipe | models | " + " | ".join(names) + " |", "|---|---:|" + "---:|" * len(names), *rows, "",
            "The chain's time per update (with Adam), by the drop from stage to stage: " + "; ".join(costs) + "."]
