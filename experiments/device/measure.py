"""What an accelerator does with this project's work: versions, matmul peak, grid FLOP/s, MJX steps/s.

    python -m experiments.device.measure --out DIR            # on a GPU (refuses a CPU-only JAX)
    python -m experiments.device.measure --out DIR --smoke    # tiny sizes, any backend (tests, this CPU)

The first step of `experiments/device/run.sh`. It prints and writes
`DIR/measure.json`:

- the versions of Python, JAX and the packages the project needs, and `jax.devices()`;
- the card's measured matmul peak: float32 and bfloat16 `n×n` products (n 8192;
  `--smoke`: 256), FLOP/s = 2n³ / the median time;
- the training grid's throughput at the `paper` preset's width (the default
  grid, 14 configurations × 5 seeds = 70 models, batch 128, the state MLP on
  Hopper `pos` shapes) as one `jit(vmap(scan))`: model-updates/s and the FLOP/s
  achieved (6 · batch · dense weights per update, as `experiments.bench_train`
  counts), against both peaks;
- MJX Hopper `pos` under the `mujoco-state` protocol (frame skip 1): control steps/s of a
  random-policy rollout at batches up to one that fills the card.

Every rate is the median of `--repeats` timed runs after a separate compiling call;
compile time is reported on its own.
"""

from __future__ import annotations

import json
import pathlib
import platform
import sys
from importlib.metadata import PackageNotFoundError, version

import jax
import jax.numpy as jnp

from experiments._cli import Parser, unwritable
from experiments._timing import rollout_throughput, time_jitted
from experiments.bench_train import ACT, BATCH, H, OBS, _data, macs_per_sample, matmul_peak

PACKAGES = ("jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "brax", "mujoco", "mujoco-mjx", "numpy")
# (matmul n, grid iterations per timed run, MJX batches, MJX steps per timed rollout)
FULL = dict(matmul=8192, iters=2_000, batches=(1_024, 8_192, 32_768), steps=200)
SMOKE = dict(matmul=256, iters=20, batches=(8,), steps=5)


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    return out


def grid_throughput(iters: int, seeds: int, repeats: int) -> dict:
    """The paper preset's default grid (BC-SO, BC-OH, 6 step, 6 softmax) × `seeds` as one vmapped scan."""
    from ape_jax import methods
    from ape_jax.learner import LearnerConfig, make_train, stack_hparams
    from ape_jax.pipeline.presets import SOFTMAX_GRID, STEP_GRID

    runs = [("bc-so", {}), ("bc-oh", {})] + [("ours-step", {"thr": t, "w": w}) for t, w in STEP_GRID] + \
           [("ours-softmax", {"tau": tau}) for tau in SOFTMAX_GRID]
    grid = [methods.get(name).hparams(settings, 2e-4, seed) for seed in range(seeds) for name, settings in runs]
    cfg = LearnerConfig(obs_shape=(OBS,), action_dim=ACT, history=H, iterations=iters, batch_size=BATCH)
    learner, data, hps = make_train(cfg), _data(), stack_hparams(grid)
    keys = jax.random.split(jax.random.PRNGKey(0), len(grid))
    states = jax.jit(jax.vmap(learner.init, (0, 0, None)))(keys, hps, data)
    run = jax.jit(jax.vmap(lambda s, hp, d: learner.run(s, hp, d, iters)[0].params, (0, 0, None)))
    compile_s, steady, _ = time_jitted(run, states, hps, data, repeats=repeats)
    macs = macs_per_sample(cfg)
    updates_s = len(grid) * iters / steady
    return {"models": len(grid), "iterations": iters, "batch": BATCH, "dense_weights": macs,
            "compile_s": compile_s, "model_updates_s": updates_s, "flops_s": 6 * BATCH * macs * updates_s}


def mjx_throughput(batches, steps: int, repeats: int) -> list[dict]:
    """Random-policy control steps/s of Hopper `pos` under `mujoco-state` (frame skip 1), per batch size."""
    import envs
    from ape_jax.pipeline.collect import protocol_setup

    setup = protocol_setup("hopper", "pos", "mujoco-state")
    env = envs.make("hopper", obs="pos", terminate_when_unhealthy=False, **setup.env_overrides)
    out = []
    for batch in batches:
        r = rollout_throughput(env, batch, steps, repeats)
        out.append({"batch": batch, "steps": steps, "compile_s": r["compile_s"], "steps_s": r["steps_per_s"]})
        print(f"  MJX hopper pos (mujoco-state, frame skip 1), batch {batch:,}: {r['steps_per_s']:,.0f} steps/s "
              f"(compile {r['compile_s']:.1f} s)", flush=True)
    return out


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.device.measure", description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="folder for measure.json (made if missing)")
    p.add_argument("--smoke", action="store_true", help="tiny sizes on any backend (a CPU check of the script)")
    p.add_argument("--seeds", type=int, default=5, help="seeds of the grid (the paper preset's 5)")
    p.add_argument("--repeats", type=int, default=3, help="timed runs; the median is reported")
    args = p.parse_args(argv)
    if args.seeds < 1 or args.repeats < 1:
        p.error("--seeds and --repeats must be >= 1")
    why = unwritable(args.out)
    if why:
        p.error(f"--out {args.out}: {why}")
    sizes = SMOKE if args.smoke else FULL
    info = {"smoke": args.smoke, "versions": versions(), "backend": jax.default_backend(),
            "devices": [str(d) for d in jax.devices()]}
    print(json.dumps(info, indent=1), flush=True)
    if not args.smoke and jax.default_backend() != "gpu":
        print(f"measure: JAX sees no GPU (backend {jax.default_backend()!r}, devices {info['devices']}); "
              "install the CUDA build, or pass --smoke for a CPU check", file=sys.stderr)
        return 2
    n = sizes["matmul"]
    info["matmul_n"] = n
    info["matmul_peak_flops_s"] = {name: matmul_peak(args.repeats, (n,), dtype)[n]
                                   for name, dtype in (("float32", jnp.float32), ("bfloat16", jnp.bfloat16))}
    print(f"matmul {n}×{n}: "
          + ", ".join(f"{k} {v / 1e12:,.2f} TFLOP/s" for k, v in info["matmul_peak_flops_s"].items()),
          flush=True)
    grid = grid_throughput(sizes["iters"], 1 if args.smoke else args.seeds, args.repeats)
    grid["fraction_of_float32_peak"] = grid["flops_s"] / info["matmul_peak_flops_s"]["float32"]
    grid["fraction_of_bfloat16_peak"] = grid["flops_s"] / info["matmul_peak_flops_s"]["bfloat16"]
    info["grid"] = grid
    print(f"grid of {grid['models']} models: {grid['model_updates_s']:,.0f} model-updates/s, "
          f"{grid['flops_s'] / 1e12:,.3f} TFLOP/s = {100 * grid['fraction_of_float32_peak']:.2f}% of the float32 "
          f"peak (compile {grid['compile_s']:.1f} s)", flush=True)
    info["mjx"] = mjx_throughput(sizes["batches"], sizes["steps"], args.repeats)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "measure.json").write_text(json.dumps(info, indent=1) + "\n")
    print(f"wrote {out / 'measure.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
