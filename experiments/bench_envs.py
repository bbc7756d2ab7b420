"""Environment throughput: MJX vs native MuJoCo, renderer frames/s, the driving tasks with images.

    python -m experiments.bench_envs                      # print the tables
    python -m experiments.bench_envs --write docs/speed.md  # also replace their sections
    python -m experiments.bench_envs --only driving       # the driving tasks' table alone (a minute)

Every figure is a median over `--repeats` timed runs after a separate first
(compiling) call; compile time is reported on its own. The driving tasks (the
pure-JAX tasks with a record, `ape_jax.tasks`) are timed in one process, their
runs interleaved, so each ratio to the first task's rate at its default image size
compares programs that met the same load; that table is its own section. Native MuJoCo runs
`mujoco.mj_step` on the same compiled model with the same number of physics
substeps per control step, single-threaded; native ray casting uses
`mujoco.mj_multiRay` with the same camera rays as our renderer (no shading).
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import jax
import numpy as np

import envs
from ape_jax import tasks
from envs._quiet import mujoco
from experiments._cli import Parser
from experiments._timing import machine, rollout_throughput, run_benchmark, time_jitted, write_section

SECTION = "bench_envs"
DRIVING_SECTION = "bench_envs_driving"


def mjx_steps(name: str, obs: str, batch: int, steps: int, repeats: int, **overrides) -> dict:
    """Batched control steps/s of `envs.rollout` with a random policy (no early termination)."""
    if name in envs.brax_env.brax_names() and "terminate_when_unhealthy" in envs.brax_env.constructor_params(name):
        overrides["terminate_when_unhealthy"] = False  # every timed step simulates
    return rollout_throughput(envs.make(name, obs=obs, **overrides), batch, steps, repeats)


def native_steps(name: str, steps: int, repeats: int) -> dict:
    """Single-threaded `mujoco.mj_step` control steps/s on the same model and substeps."""
    env = envs.make(name, obs="full")
    model = env.brax_env.sys.mj_model
    data = mujoco.MjData(model)
    n_frames = env.brax_env._n_frames
    rng = np.random.default_rng(0)
    ctrl = rng.uniform(-1, 1, (steps, model.nu))
    rates = []
    for _ in range(repeats):
        mujoco.mj_resetData(model, data)
        t0 = time.perf_counter()
        for t in range(steps):
            data.ctrl[:] = ctrl[t]
            for _ in range(n_frames):
                mujoco.mj_step(model, data)
        rates.append(steps / (time.perf_counter() - t0))
    return {"steps_per_s": statistics.median(rates), "substeps": n_frames}


def render_fps(name: str, size: int, batch: int, repeats: int) -> dict:
    """Frames/s of the in-jit renderer over a vmapped batch of states, and of native mj_multiRay."""
    env = envs.make(name, obs="image", image_size=size)
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), batch))
    render = jax.jit(jax.vmap(env.render))
    compile_s, steady_s, _ = time_jitted(render, states, repeats=repeats)
    # native: the same rays through mujoco.mj_multiRay, one frame at a time
    model = env.brax_env.sys.mj_model
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    cam = env.camera
    dirs = cam.ray_directions().astype(np.float64)
    origin = np.asarray(cam.origin(data.xpos[cam.track_body]), np.float64)
    geomid = np.zeros(len(dirs), np.int32)
    dist = np.zeros(len(dirs), np.float64)
    frames = 20
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(frames):
            mujoco.mj_multiRay(model, data, origin, dirs.ravel(), None, 1, -1, geomid, dist, None, len(dirs),
                               mujoco.mjMAXVAL)
        rates.append(frames / (time.perf_counter() - t0))
    return {"compile_s": compile_s, "fps": batch / steady_s, "native_fps": statistics.median(rates)}


def table(args) -> str:
    lines = [
        "## Environment throughput",
        "",
        f"Command: `python -m experiments.bench_envs --batch {args.batch} --steps {args.steps} "
        f"--repeats {args.repeats}`  ",
        f"Machine: {machine()}  ",
        f"Medians of {args.repeats} runs after one compiling call; compile time apart. "
        "MJX: `envs.rollout` of a uniform-random policy, vmapped over the batch, scanned over steps "
        "(termination off, so every step simulates). Native: `mujoco.mj_step`, single thread, same model and substeps.",
        "",
        "| env (obs) | batch | MJX env steps/s | compile s | native MuJoCo env steps/s | substeps |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name in envs.MUJOCO_TASKS:
        m = mjx_steps(name, "pos", args.batch, args.steps, args.repeats)
        n = native_steps(name, args.steps * 4, args.repeats)
        lines.append(f"| {name} (pos) | {args.batch} | {m['steps_per_s']:,.0f} | {m['compile_s']:.1f} | "
                     f"{n['steps_per_s']:,.0f} | {n['substeps']} |")
        print(lines[-1], file=sys.stderr)
    lines += [
        "",
        f"Rendering (hopper, batch {args.render_batch} of reset states, `jit(vmap(env.render))`); "
        "native: `mujoco.mj_multiRay` with the same rays, one frame at a time, ray casting only (no shading):",
        "",
        "| size | MJX frames/s | compile s | native mj_multiRay frames/s |",
        "|---|---:|---:|---:|",
    ]
    for size in (64, 128):
        r = render_fps("hopper", size, args.render_batch, args.repeats)
        lines.append(f"| {size}×{size} | {r['fps']:,.0f} | {r['compile_s']:.1f} | {r['native_fps']:,.0f} |")
        print(lines[-1], file=sys.stderr)
    return "\n".join(lines) + "\n"


def _random_rollout(env, batch: int, steps: int):
    """A jitted `key -> returns` of `envs.rollout` with a uniform-random policy that reads the observation (as
    `rollout_throughput`'s: otherwise XLA drops the rendering nothing consumes)."""
    import jax.numpy as jnp

    low, high = env.action_bounds
    low, high = jnp.maximum(low, -1.0), jnp.minimum(high, 1.0)

    def act(params, state, key):
        seen = 1e-12 * jnp.mean(state.obs.astype(jnp.float32))
        return jax.random.uniform(key, low.shape, minval=low, maxval=high) + seen

    return jax.jit(lambda k: envs.rollout(env, envs.stateless(act), None, k, batch, steps).returns)


def driving_table(args) -> str:
    """Each driving task at its default image size, at the other of 128 and 64 pixels, and on its full state,
    timed interleaved (one run of each in turn, `--repeats` rounds), with the ratio to the first task's default
    image rate."""
    names = [n for n in tasks.sweepable() if n not in envs.brax_env.brax_names()]
    rows = []  # (label, env, default image?)
    for name in names:
        own = envs.make(name, obs="image").config.image_size
        sizes = [own] + [(s, s) for s in (128, 64) if (s, s) != tuple(own)]
        rows += [(f"{name} (image {h}×{w})", envs.make(name, obs="image", image_size=(h, w)), (h, w) == tuple(own))
                 for h, w in sizes]
        rows.append((f"{name} (full)", envs.make(name, obs="full"), False))
    load_before = os.getloadavg()
    runs, compile_s = [], []
    for _, env, _ in rows:
        run = _random_rollout(env, args.batch, args.steps)
        t0 = time.perf_counter()
        jax.block_until_ready(run(jax.random.PRNGKey(0)))
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        jax.block_until_ready(run(jax.random.PRNGKey(1)))
        compile_s.append(max(first - (time.perf_counter() - t0), 0.0))
        runs.append(run)
    times = [[] for _ in rows]
    for r in range(args.repeats):
        for i, run in enumerate(runs):
            t0 = time.perf_counter()
            jax.block_until_ready(run(jax.random.PRNGKey(2 + r)))
            times[i].append(time.perf_counter() - t0)
    load_after = os.getloadavg()
    rates = [args.batch * args.steps / statistics.median(t) for t in times]
    ref = next(i for i, row in enumerate(rows) if row[2])
    lines = [
        "## Driving tasks' throughput",
        "",
        f"Command: `python -m experiments.bench_envs --only driving --batch {args.batch} --steps {args.steps} "
        f"--repeats {args.repeats}`  ",
        f"Machine: {machine()}; load average {load_before[0]:.1f} before, {load_after[0]:.1f} after (1 min)  ",
        f"`envs.rollout` of a uniform-random policy that reads the observation, vmapped over the batch, scanned over "
        f"steps; every configuration compiled first, then one run of each in turn, {args.repeats} rounds (medians), so "
        f"the ratios compare runs that met the same load. Ratio: to {rows[ref][0]}.",
        "",
        "| env (obs) | batch | env steps/s | compile s | ratio |",
        "|---|---:|---:|---:|---:|",
    ]
    for (label, _, _), rate, c in zip(rows, rates, compile_s):
        lines.append(f"| {label} | {args.batch} | {rate:,.0f} | {c:.1f} | {rate / rates[ref]:.2f}× |")
        print(lines[-1], file=sys.stderr)
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.bench_envs", description=__doc__.splitlines()[0])
    p.add_argument("--batch", type=int, default=128, help="environments stepped in parallel (vmap)")
    p.add_argument("--steps", type=int, default=100, help="control steps per timed rollout")
    p.add_argument("--render-batch", type=int, default=32, help="states rendered per timed call")
    p.add_argument("--repeats", type=int, default=5, help="timed runs; the median is reported")
    p.add_argument("--only", choices=("all", "driving"), default="all",
                   help="driving: the driving tasks' table alone (its own section of --write's file)")
    only = p.parse_known_args(argv)[0].only
    driving = {}

    def tables(args):  # the driving table is timed first and written to its own section below
        driving["args"], driving["text"] = args, driving_table(args)
        return driving["text"] if only == "driving" else table(args)

    counts = ("--batch", "--steps", "--render-batch", "--repeats")
    status = run_benchmark(p, argv, counts, tables, DRIVING_SECTION if only == "driving" else SECTION)
    args = driving.get("args")
    if status == 0 and only == "all" and args is not None:
        print(driving["text"])
        if args.write:
            write_section(args.write, driving["text"], DRIVING_SECTION)
            print(f"wrote the driving section to {args.write}")
    return status


if __name__ == "__main__":
    sys.exit(main())
