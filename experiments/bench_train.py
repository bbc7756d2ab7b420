"""Training and evaluation speed: the vmapped grid vs one-after-another JAX vs plain PyTorch; FLOP/s; evaluation.

    python -m experiments.bench_train                        # print the tables
    python -m experiments.bench_train --write docs/speed.md  # also replace its section

Everything runs in one process, one after another, on the same data (the
hopper `pos` demonstrations shapes: input 2 × 5, action 3, batch 128):

1. model-updates/s of the grid (BC-OH + 6 step + 6 softmax configurations)
   as one `jit(vmap(scan))`; of the same 13 configurations trained one after
   another, each a jitted scan; and of a plain PyTorch loop of the same network,
   loss and optimiser, one configuration after another (the original code's
   way; needs `pip install torch==2.13.0`, the CPU build);
2. the grid step's achieved FLOP/s (analytic count: 6 · batch · MACs per
   update) against the machine's float32 matmul peak measured here;
3. evaluation env steps/s (jitted, vmapped over policies × episodes, the
   policy included) against native MuJoCo stepping the same model with the same
   network (PyTorch, one step at a time) in a Python loop;
4. model-updates/s of the same grid under each recipe (`ape_jax.pipeline.presets.RECIPES`: `mlp`, batch
   128; `bn-mlp`, the FCA code's BatchNorm network at batch 64), one after another in this run;
5. end-to-end wall time of the sweeps whose `results.json` are given;
6. the methods after the paper (`rap`, `palr`, `mine`, and the fixes after them: `channel-dropout`, `ptp`,
   `action-chunks`, `priming`; `ape_jax.baselines`) against BC-OH: model-updates/s of
   13 configurations of each as one `jit(vmap(scan))` under the recipes `bn-mlp`, `mlp` and `mlp-b1024` (batch 1,024,
   fewer iterations per timed call), the timed calls interleaved (BC-OH, RAP, PALR, MINE, BC-OH, ...) so a
   machine under shifting load slows all alike; and PALR's HSCIC estimator (value and gradient, a 100-unit
   embedding) against one BC-OH step at batches of 64 to 1,024 (`--methods-only`: this part alone, written to
   its own section);
7. the share of the float32 matmul peak (measured in the same run) that BC-OH grids of 13, 32 and 64 models
   reach under each recipe (`bn-mlp`, `mlp`, `mlp-b1024`), in one process of every thread and as one process per core,
   each pinned (`taskset`) and single-threaded, side by side, each with its share of the models (`--share`:
   this part alone, written to its own section), with where one core's time goes under `bn-mlp` and `mlp`: the
   network's dense products alone, then BatchNorm, then Adam, beside the learner's own step.

Medians of `--repeats` timed runs after a separate compiling call.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import methods
from ape_jax.grid import grid_runner
from ape_jax.learner import Data, Hparams, LearnerConfig, make_train, stack_hparams
from ape_jax.pipeline.presets import RECIPES
from ape_jax.weighting import SOFTMAX_GRID, STEP_GRID
from experiments._cli import Parser
from experiments._timing import machine, run_benchmark, time_jitted
from experiments._bench_common import ACT, BATCH, H, OBS, _data, macs_per_sample, matmul_peak, recipe_config  # noqa: F401

SECTION = "bench_train"
METHODS_SECTION = "bench_train_methods"
SHARE_SECTION = "bench_train_share"
# the methods after the paper, and the fixes after them (issue 59), each in its own program
NEW_METHODS = ("rap", "palr", "mine", "channel-dropout", "ptp", "action-chunks", "priming")
HSCIC_BATCHES = (64, 128, 256, 512, 1024)


def _grid() -> list[Hparams]:
    runs = [("bc-oh", {})] + [("ours-step", {"thr": t, "w": w}) for t, w in STEP_GRID] + \
           [("ours-softmax", {"tau": tau}) for tau in SOFTMAX_GRID]
    return [methods.get(name).hparams(settings, 2e-4, 0) for name, settings in runs]


def recipe_throughput(iters: int, repeats: int) -> dict[str, dict]:
    """Per recipe: the grid's model-updates/s (steady state) and compile time, one recipe after another, trained
    as the sweep trains it (`grid.grid_runner`) with the whole grid in one call and at `Budget.width` 1."""
    out = {}
    for name in RECIPES:
        cfg = recipe_config(name, iters)
        learner, data, hps = make_train(cfg), _data(), stack_hparams(_grid())
        keys = jax.random.split(jax.random.PRNGKey(0), len(_grid()))
        states = jax.jit(jax.vmap(learner.init, (0, 0, None)))(keys, hps, data)
        rates = {}
        for width in (None, 1):
            run = grid_runner(lambda s, hp, d: learner.run(s, hp, d, iters)[0].params, width=width)
            compile_s, steady, _ = time_jitted(run, states, hps, data, repeats=repeats)
            rates[width] = len(_grid()) * iters / steady, compile_s
        out[name] = {"batch": cfg.batch_size, "network": cfg.network, "updates_s": rates[None][0],
                     "samples_s": rates[None][0] * cfg.batch_size, "compile_s": rates[None][1],
                     "width1_updates_s": rates[1][0], "width1_compile_s": rates[1][1]}
    return out


def jax_throughput(iters: int, repeats: int) -> dict:
    cfg = LearnerConfig(obs_shape=(OBS,), action_dim=ACT, history=H, iterations=iters, batch_size=BATCH)
    learner = make_train(cfg)
    data, grid = _data(), _grid()
    g = len(grid)
    keys = jax.random.split(jax.random.PRNGKey(0), g)
    hps = stack_hparams(grid)
    states = jax.jit(jax.vmap(learner.init, (0, 0, None)))(keys, hps, data)
    run_grid = jax.jit(jax.vmap(lambda s, hp, d: learner.run(s, hp, d, iters)[0].params, (0, 0, None)))
    compile_g, steady_g, _ = time_jitted(run_grid, states, hps, data, repeats=repeats)
    run_one = jax.jit(lambda s, hp, d: learner.run(s, hp, d, iters)[0].params)
    singles = [jax.tree.map(lambda x: x[i], (states, hps)) for i in range(g)]
    jax.block_until_ready(run_one(*singles[0], data))  # compile once: every config has the same shapes
    seq = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for s, hp in singles:
            jax.block_until_ready(run_one(s, hp, data))
        seq.append(time.perf_counter() - t0)
    return {"models": g, "grid_updates_s": g * iters / steady_g, "grid_compile_s": compile_g,
            "seq_updates_s": g * iters / statistics.median(seq), "macs": macs_per_sample(cfg)}


def _method_program(name: str, cfg: LearnerConfig, iters: int, data: Data, configs: int, **learner_kw):
    """A method's grid of `configs` copies of its default setting (different keys) as the sweep trains it: the
    jitted runner of `iters` iterations and its arguments. `learner_kw` goes to the method's learner factory
    (`mine`'s `inner_steps`)."""
    from ape_jax import tasks
    from ape_jax.baselines.mine import make_mine

    method = methods.get(name)
    if method.history is not None:   # action-chunks: the current observation only, as the sweep trains it
        cfg = dataclasses.replace(cfg, history=method.history)
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=data.size)
    if method.learner is None:
        learner = make_train(cfg)
    elif learner_kw:
        learner = make_mine(cfg, **learner_kw)
    else:
        learner = method.learner(methods.LearnerContext(cfg=cfg, env=None, expert=None, obs_mean=None,
                                                        obs_std=None, n_train=data.size))
    hps = stack_hparams([method.hparams(method.settings(ctx)[0], 2e-4, 0)] * configs)
    keys = jax.random.split(jax.random.PRNGKey(0), configs)
    if method.reads is not None and (read := method.reads(ctx)):   # priming: BC-SO's policies, untrained here
        other = dataclasses.replace(cfg, history=methods.get(read).history or cfg.history)
        hps = hps.read(jax.vmap(lambda k: make_train(other).init_policy(k, data))(keys))
    states = jax.jit(jax.vmap(learner.init, (0, 0, None)))(keys, hps, data)
    run = grid_runner(lambda s, hp, d: learner.policy_params(learner.run(s, hp, d, iters)[0]), width=None)
    return run, (states, hps, data)


def methods_throughput(iters: int, repeats: int, configs: int = 13) -> dict[str, dict]:
    """Per recipe (`bn-mlp`, `mlp`, `mlp-b1024`): model-updates/s of `configs` configurations of BC-OH, RAP, PALR, MINE
    (and MINE at the authors' 5 estimator steps) in one `jit(vmap(scan))` each, timed calls interleaved; the
    `mlp-b1024` recipe's batch of 1,024 runs `iters · 128 / 1024` iterations per call."""
    out = {}
    rows = [("bc-oh", {}), *((m, {}) for m in NEW_METHODS), ("mine", {"inner_steps": 5})]
    for recipe in ("bn-mlp", "mlp", "mlp-b1024"):
        cfg = recipe_config(recipe, iters)
        n = max(10, iters * BATCH // cfg.batch_size)
        cfg = recipe_config(recipe, n)
        data = _data()
        programs = [_method_program(name, cfg, n, data, configs, **kw) for name, kw in rows]
        for run, args in programs:
            jax.block_until_ready(run(*args))  # compile
        times = [[] for _ in programs]
        for _ in range(repeats):
            for i, (run, args) in enumerate(programs):
                t0 = time.perf_counter()
                jax.block_until_ready(run(*args))
                times[i].append(time.perf_counter() - t0)
        rates = [configs * n / statistics.median(t) for t in times]
        names = [name + ("" if not kw else " (5 estimator steps)") for name, kw in rows]
        out[recipe] = {"batch": cfg.batch_size, "iterations": n, "updates_s": dict(zip(names, rates))}
    return out


def hscic_cost(repeats: int) -> dict[int, dict]:
    """Per batch `n`: seconds of PALR's HSCIC estimator's value and gradient on `n` rows (a 100-unit embedding,
    3-d actions) and of one BC-OH update at batch `n` (the `mlp` recipe's network), medians, interleaved."""
    from ape_jax.baselines.palr import hscic

    out = {}
    for n in HSCIC_BATCHES:
        keys = jax.random.split(jax.random.PRNGKey(n), 3)
        x = jax.random.normal(keys[0], (n, 100))
        y, z = (jnp.tanh(jax.random.normal(k, (n, ACT))) for k in keys[1:])
        estimator = jax.jit(jax.value_and_grad(lambda x, y, z: hscic(x, y, z, 1.0)))
        steps = 20
        cfg = LearnerConfig(obs_shape=(OBS,), action_dim=ACT, history=H, iterations=steps, batch_size=n,
                            lr_boundaries=())
        learner, data = make_train(cfg), _data()
        state = learner.init(jax.random.PRNGKey(0), Hparams.make(), data)
        bc = jax.jit(lambda s: learner.run(s, Hparams.make(), data, steps)[0].params)
        jax.block_until_ready(estimator(x, y, z))
        jax.block_until_ready(bc(state))
        est, step = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(estimator(x, y, z))
            est.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            jax.block_until_ready(bc(state))
            step.append((time.perf_counter() - t0) / steps)
        out[n] = {"hscic_s": statistics.median(est), "bc_step_s": statistics.median(step)}
    return out


def methods_table(args) -> str:
    """The methods-after-the-paper part (6. in the module docstring) as Markdown."""
    rates = methods_throughput(args.iters, args.repeats)
    cost = hscic_cost(args.repeats)
    cmd = f"python -m experiments.bench_train --methods-only --iters {args.iters} --repeats {args.repeats}"
    names = list(next(iter(rates.values()))["updates_s"])
    lines = [
        "## The methods after the paper: training speed", "", f"Command: `{cmd}`  ", f"Machine: {machine()}  ",
        f"Medians of {args.repeats} timed calls after a compiling call, the methods' calls interleaved; 13 "
        "configurations of each method's default setting in one `jit(vmap(scan))`; the state policy on the "
        f"benchmark's shapes (input {H}×{OBS}, {ACT} actions). The budget: each method at most 1.5× BC-OH's time "
        "per update (BC-OH ÷ method >= 0.67).", "",
        "| recipe | batch | iterations per call | " + " | ".join(names) + " |",
        "|---|---:|---:|" + "---:|" * len(names),
        *[f"| `{recipe}` | {r['batch']} | {r['iterations']} | "
          + " | ".join(f"{v:,.0f}" + ("" if name == "bc-oh" else f" ({v / r['updates_s']['bc-oh']:.2f}×)")
                       for name, v in r["updates_s"].items()) + " |"
          for recipe, r in rates.items()],
        "", "Model-updates/s; in brackets the method's rate ÷ BC-OH's, measured in the same run.", "",
        "| batch | HSCIC value and gradient, ms | one BC-OH update, ms | ratio |", "|---:|---:|---:|---:|",
        *[f"| {n} | {c['hscic_s'] * 1e3:,.2f} | {c['bc_step_s'] * 1e3:,.2f} | {c['hscic_s'] / c['bc_step_s']:.2f} |"
          for n, c in cost.items()],
        "", "PALR's estimator and MINE's bound read at most 256 rows of a minibatch (`palr.rows`, "
        "`mine.rows`): every recipe's batch up to 256 is read whole, PALR's own 1,024 on its first 256.",
    ]
    for line in lines[4:]:
        print(line, file=sys.stderr)
    return "\n".join(lines) + "\n"


def torch_throughput(iters: int, repeats: int, configs: int) -> float | None:
    try:
        import torch
    except ImportError:
        return None
    torch.set_num_threads(os.cpu_count() or 1)
    data = _data()
    obs = torch.tensor(np.asarray(data.obs))
    act = torch.tensor(np.asarray(data.action))

    def net():
        lrelu = torch.nn.LeakyReLU(0.2)
        return torch.nn.Sequential(torch.nn.Linear(H * OBS, 300), lrelu, torch.nn.Linear(300, 300), lrelu,
                                   torch.nn.Linear(300, 300), lrelu, torch.nn.Linear(300, 100),
                                   torch.nn.Linear(100, 300), lrelu, torch.nn.Linear(300, ACT))

    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(configs):
            model = net()
            opt = torch.optim.Adam(model.parameters(), lr=2e-4)
            for _ in range(iters):
                idx = torch.randint(0, len(obs) - 1, (BATCH,))
                x = torch.cat([obs[idx], obs[idx + 1]], dim=1)
                w = torch.ones(BATCH)
                loss = (w * ((model(x) - act[idx + 1]) ** 2).sum(-1)).mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
        times.append(time.perf_counter() - t0)
    return configs * iters / statistics.median(times)



def eval_throughput(policies: int, episodes: int, repeats: int) -> dict:
    import envs
    from ape_jax import evaluate

    env = envs.make("hopper", obs="pos")
    cfg = LearnerConfig(obs_shape=(OBS,), action_dim=ACT, history=H, iterations=1, batch_size=BATCH)
    params = jax.vmap(lambda k: cfg.model().init(k, jnp.zeros((1, H * OBS))))(
        jax.random.split(jax.random.PRNGKey(0), policies))
    out = {}
    for width in (None, 1):  # every policy in one call; one at a time (`Budget.width` 1, the sweep's default)
        run = evaluate.make_evaluator(env, cfg, jnp.zeros(OBS), jnp.ones(OBS), episodes, steps=200, width=width)
        compile_s, steady, _ = time_jitted(run, params, jax.random.PRNGKey(1), repeats=repeats)
        out[width] = compile_s, policies * episodes * 200 / steady
    return {"compile_s": out[None][0], "steps_s": out[None][1], "width1_compile_s": out[1][0],
            "width1_steps_s": out[1][1], "native_steps_s": _native_eval(env, steps=1000, repeats=repeats)}


def _native_eval(env, steps: int, repeats: int) -> float | None:
    try:
        import torch
    except ImportError:
        return None
    from envs._quiet import mujoco

    model = env.brax_env.sys.mj_model
    data = mujoco.MjData(model)
    n_frames = env.brax_env._n_frames
    lrelu = torch.nn.LeakyReLU(0.2)
    net = torch.nn.Sequential(torch.nn.Linear(H * OBS, 300), lrelu, torch.nn.Linear(300, 300), lrelu,
                              torch.nn.Linear(300, 300), lrelu, torch.nn.Linear(300, 100),
                              torch.nn.Linear(100, 300), lrelu, torch.nn.Linear(300, ACT))
    rates = []
    for _ in range(repeats):
        mujoco.mj_resetData(model, data)
        prev = data.qpos[1:].copy()
        t0 = time.perf_counter()
        with torch.no_grad():
            for _ in range(steps):
                obs = data.qpos[1:].copy()
                x = torch.tensor(np.concatenate([prev, obs]), dtype=torch.float32)[None]
                data.ctrl[:] = np.clip(net(x)[0].numpy(), -1, 1)
                for _ in range(n_frames):
                    mujoco.mj_step(model, data)
                prev = obs
        rates.append(steps / (time.perf_counter() - t0))
    return statistics.median(rates)


def table(args) -> str:
    if args.methods_only:
        return methods_table(args)
    if args.share:
        from experiments._share import share_table
        return share_table(args)
    t = jax_throughput(args.iters, args.repeats)
    torch_rate = torch_throughput(args.torch_iters, args.repeats, t["models"])
    peak = matmul_peak(args.repeats)
    flops = 6 * BATCH * t["macs"] * t["grid_updates_s"]
    ev = eval_throughput(args.policies, args.episodes, args.repeats)
    recipes = recipe_throughput(args.iters, args.repeats)
    cmd = (f"python -m experiments.bench_train --iters {args.iters} --torch-iters {args.torch_iters} "
           f"--repeats {args.repeats}")
    lines = [
        "## Training and evaluation speed", "", f"Command: `{cmd}`  ", f"Machine: {machine()}  ",
        f"Medians of {args.repeats} runs after a compiling call; all figures from one run of the script. "
        f"Network: the state policy ({t['macs']:,} weights in dense layers), batch {BATCH}, input {H}×{OBS}, "
        f"Adam; {t['models']} configurations (BC-OH, 6 step, 6 softmax).", "",
        "| training | model-updates/s | vs PyTorch |", "|---|---:|---:|",
        f"| JAX, the grid as one `jit(vmap(scan))` | {t['grid_updates_s']:,.0f} | "
        + (f"{t['grid_updates_s'] / torch_rate:.1f}× |" if torch_rate else "– |"),
        f"| JAX, one configuration after another (jitted scan each) | {t['seq_updates_s']:,.0f} | "
        + (f"{t['seq_updates_s'] / torch_rate:.1f}× |" if torch_rate else "– |"),
        f"| PyTorch {'(' + str(args.torch_iters) + ' updates per config)' if torch_rate else 'not installed'}, "
        f"one configuration after another | {torch_rate or 0:,.0f} | 1.0× |", "",
        f"Grid compile: {t['grid_compile_s']:.1f} s. Grid vs one-after-another JAX: "
        f"{t['grid_updates_s'] / t['seq_updates_s']:.2f}×.", "",
        "| float32 matmul n×n | GFLOP/s |", "|---|---:|",
        *[f"| {n} | {v / 1e9:,.1f} |" for n, v in peak.items()], "",
        f"Grid training step: {flops / 1e9:,.1f} GFLOP/s achieved (6 · batch · weights per update) = "
        f"**{100 * flops / peak[max(peak)]:.0f}%** of the largest-matrix peak "
        f"({100 * flops / max(peak.values()):.0f}% of the best measured).", "",
        "| evaluation (hopper, pos) | env steps/s, policy included |", "|---|---:|",
        f"| JAX: {args.policies} policies × {args.episodes} episodes, vmapped, 200-step scan | {ev['steps_s']:,.0f} "
        f"(compile {ev['compile_s']:.1f} s) |",
        f"| the same, one policy per call (`budget.width` 1, the sweep's default) | {ev['width1_steps_s']:,.0f} "
        f"(compile {ev['width1_compile_s']:.1f} s) |",
        "| native MuJoCo + PyTorch policy, Python loop, one env | "
        + (f"{ev['native_steps_s']:,.0f} |" if ev["native_steps_s"] else "torch not installed |"), "",
        f"Per recipe (`--recipe`), the same {t['models']} configurations as the sweep trains them "
        "(`grid.grid_runner`), one recipe after the other in this run: the whole grid in one `jit(vmap(scan))`, "
        "and one configuration per call (`budget.width` 1, the sweep's default: a configuration's numbers then do "
        "not depend on what trains beside it):", "",
        "| recipe | network | batch | model-updates/s | samples/s | compile s | width 1: model-updates/s | "
        "width 1 ÷ whole |", "|---|---|---:|---:|---:|---:|---:|---:|",
        *[f"| `{name}` | {r['network']} | {r['batch']} | {r['updates_s']:,.0f} | {r['samples_s']:,.0f} | "
          f"{r['compile_s']:.1f} | {r['width1_updates_s']:,.0f} | {r['width1_updates_s'] / r['updates_s']:.2f} |"
          for name, r in recipes.items()],
    ]
    if args.results:
        lines += ["", "| sweep (results.json) | total s | compile s | train s | evaluate s |",
                  "|---|---:|---:|---:|---:|"]
        for path in args.results:
            r = json.loads(pathlib.Path(path).read_text())
            tm = r["timing"]
            c = r["config"]
            cmd = (f"python -m experiments.sweep --env {r['env']} --obs {r['obs']} --preset {r['preset']} "
                   f"--iterations {c['iterations']} --seeds {c['seeds']} --eval-episodes {c['eval_episodes']}")
            lines.append(f"| `{cmd}` | {tm['total_s']:,.0f} | {tm['compile_s']:,.0f} | "
                         f"{tm['train_s']:,.0f} | {tm['eval_s']:,.0f} |")
    for line in lines[6:]:
        print(line, file=sys.stderr)
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.bench_train", description=__doc__.splitlines()[0])
    p.add_argument("--iters", type=int, default=500, help="updates per model in a timed JAX run")
    p.add_argument("--torch-iters", type=int, default=200, help="updates per configuration in a timed PyTorch run")
    p.add_argument("--policies", type=int, default=13, help="policies evaluated at once")
    p.add_argument("--episodes", type=int, default=8, help="episodes per policy")
    p.add_argument("--repeats", type=int, default=3, help="timed runs; the median is reported")
    p.add_argument("--results", nargs="*", default=[], help="results.json files whose end-to-end timing to report")
    p.add_argument("--methods-only", action="store_true",
                   help="time only the methods after the paper against BC-OH, and PALR's estimator (its own section)")
    p.add_argument("--share", action="store_true",
                   help="only the share of the matmul peak per recipe and grid size, one process and one per core "
                        "(its own section)")
    p.add_argument("--share-worker", metavar="RECIPE:MODELS:ITERS:REPEATS", help=argparse.SUPPRESS)
    given = sys.argv[1:] if argv is None else argv
    if "--share-worker" in given:   # one pinned process of `--share`: its rate as one JSON line
        from experiments._share import grid_rate, profile_rates

        spec = p.parse_args(given).share_worker.split(":")
        if spec[0] == "profile":   # profile:RECIPE:ITERS:REPEATS
            print(json.dumps(profile_rates(spec[1], int(spec[2]), int(spec[3]))))
        else:
            recipe, models, iters, repeats = spec
            print(json.dumps(grid_rate(recipe, int(models), int(iters), int(repeats))))
        return 0
    if "--methods-only" in given and "--share" in given:
        p.error("--methods-only and --share each write a section of their own: give one")
    section = METHODS_SECTION if "--methods-only" in given else SHARE_SECTION if "--share" in given else SECTION
    return run_benchmark(p, argv, ("--iters", "--torch-iters", "--policies", "--episodes", "--repeats"), table,
                         section, check=_check_results)


def _check_results(args) -> str | None:
    """Why a `--results` file cannot be reported (they are read at the end, so checked first), or None."""
    timing, config = ("total_s", "compile_s", "train_s", "eval_s"), ("iterations", "seeds", "eval_episodes")
    from experiments._cli import unreadable

    for path in args.results:
        if why := unreadable(path, "a results file"):
            return f"--results {why}"
        try:
            r = json.loads(pathlib.Path(path).read_text())
        except (OSError, UnicodeDecodeError, ValueError) as e:
            return f"--results {path}: cannot read it as JSON ({e})"
        ok = (isinstance(r, dict) and all(k in r for k in ("env", "obs", "preset"))
              and isinstance(r.get("timing"), dict) and all(k in r["timing"] for k in timing)
              and isinstance(r.get("config"), dict) and all(k in r["config"] for k in config))
        if not ok:
            return (f"--results {path}: not a sweep results file (needs env, obs, preset, config with "
                    f"{', '.join(config)} and timing with {', '.join(timing)})")
    return None


if __name__ == "__main__":
    sys.exit(main())
