"""Environment throughput: MJX vs native MuJoCo, renderer frames/s, ToyCar with images.

    python -m experiments.bench_envs                      # print the table
    python -m experiments.bench_envs --write docs/speed.md  # also replace its section

Every figure is a median over `--repeats` timed runs after a separate first
(compiling) call; compile time is reported on its own. Native MuJoCo runs
`mujoco.mj_step` on the same compiled model with the same number of physics
substeps per control step, single-threaded; native ray casting uses
`mujoco.mj_multiRay` with the same camera rays as our renderer (no shading).
"""

from __future__ import annotations

import statistics
import sys
import time

import jax
import numpy as np

import envs
from ape_jax import tasks
from envs._quiet import mujoco
from experiments._cli import Parser
from experiments._timing import machine, rollout_throughput, run_benchmark, time_jitted

SECTION = "bench_envs"


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
    lines += ["", "| env (obs) | batch | env steps/s | compile s |", "|---|---:|---:|---:|"]
    pure_jax = [n for n in tasks.sweepable() if n not in envs.brax_env.brax_names()]  # the driving sandbox
    for name, obs, size in ((n, obs, size) for n in pure_jax for obs, size in (("image", 128), ("image", 64),
                                                                                ("full", None))):
        kw = {"image_size": size} if size else {}
        m = mjx_steps(name, obs, args.batch, args.steps, args.repeats, **kw)
        label = f"{name} ({obs}{f' {size}×{size}' if size else ''})"
        lines.append(f"| {label} | {args.batch} | {m['steps_per_s']:,.0f} | {m['compile_s']:.1f} |")
        print(lines[-1], file=sys.stderr)
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.bench_envs", description=__doc__.splitlines()[0])
    p.add_argument("--batch", type=int, default=128, help="environments stepped in parallel (vmap)")
    p.add_argument("--steps", type=int, default=100, help="control steps per timed rollout")
    p.add_argument("--render-batch", type=int, default=32, help="states rendered per timed call")
    p.add_argument("--repeats", type=int, default=5, help="timed runs; the median is reported")
    return run_benchmark(p, argv, ("--batch", "--steps", "--render-batch", "--repeats"), table, SECTION)


if __name__ == "__main__":
    sys.exit(main())
