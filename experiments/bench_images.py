"""Image policies' training and evaluation speed, and memory: `python -m experiments.bench_images`.

    python -m experiments.bench_images                        # print the table
    python -m experiments.bench_images --write docs/speed.md  # also replace its section
    python -m experiments.bench_images --encoders patch@64,drq@84 --dtype float32,bfloat16 --no-eval

For the image policies the sweep trains (frames stacked on channels, history
2, batch 128, random uint8 frames):

1. model-updates/s per encoder, image size and arithmetic dtype (`recipe.dtype`:
   float32, or bfloat16 mixed precision), trained the way the sweep
   trains that encoder on this backend (`ape_jax.pipeline.sweep.trains_sequentially`):
   a convolutional encoder on a CPU one configuration at a time, one chunk of
   `ape_jax.pipeline.training.CPU_IMAGE_CHUNK` unrolled iterations per call (XLA:CPU is slow
   at convolution gradients inside loops and under vmap); otherwise scanned
   chunks of `SCAN_CHUNK` iterations. With `--grid G` also `G` configurations
   as one vmapped program in the same chunks (the sweep's way for a loop-friendly
   encoder such as "patch"; for a convolutional one on a CPU, the way it avoids),
   counted as G model-updates per iteration. The last column is the rate against
   the table's first row (the first encoder, size and dtype, one configuration);
2. evaluation policy-steps/s of the image evaluator on hopper (rendering
   inside the jitted rollout, each encoder's policy, vmapped over policies × episodes);
3. the process's peak resident memory when done.

Medians of `--repeats` timed runs after a separate compiling call. An encoder
may name its own size, `drq@84`, in place of every `--sizes`: one run compares
the drq encoder at 84×84 with the patch encoder at 64×64 on the same machine.
"""

from __future__ import annotations

import resource
import sys

import jax
import jax.numpy as jnp
import numpy as np

from experiments._cli import Parser
from experiments._timing import machine, run_benchmark, time_jitted

SECTION = "bench_images"
H, BATCH, ACT = 2, 128, 3
SCAN_CHUNK = 100  # iterations per call of a scanned chunk


def split_encoder(name: str) -> tuple[str, str]:
    """`"patch+group"` -> `("patch", "group")`: an encoder and its normalisation (`recipe.encoder_norm`); a size
    (`"drq@84"`, `sized`) is dropped."""
    encoder, _, norm = name.partition("@")[0].partition("+")
    return encoder, norm or "none"


def sized(name: str, sizes: list[int]) -> list[int]:
    """The image sides `name` is timed at: its own (`"drq@84"` -> `[84]`) or every one of `sizes`."""
    _, at, size = name.partition("@")
    return [int(size)] if at else sizes


def update_flops(encoder: str, size: int, dtype: str = "float32", batch: int = BATCH,
                 perception_sha256: str = "") -> float | None:
    """FLOPs of one model update (forward, backward, Adam) of `encoder` at `size`×`size`, batch `batch`, history
    `H`, as XLA counts them in the lowered program (`cost_analysis`; nothing compiles or runs); None where the
    backend gives no count. `"perception"`: the pretrained encoder of SHA-256 `perception_sha256` (loaded)."""
    from ape_jax.learner import Data, Hparams, LearnerConfig, make_train

    encoder, norm = split_encoder(encoder)
    cfg = LearnerConfig(obs_shape=(size, size, 3), action_dim=ACT, history=H, batch_size=batch, unroll=True,
                        encoder=encoder, encoder_norm=norm, dtype=dtype, perception_sha256=perception_sha256)
    n = 2 * batch
    data = Data(obs=jnp.zeros((n, size, size, 3), jnp.uint8), action=jnp.zeros((n, ACT)),
                t=jnp.arange(n, dtype=jnp.int32) % 100, ape=jnp.ones(n))
    learner, hp = make_train(cfg), Hparams.make("step", thr=0.1, w=5.0, lr=2e-4)
    state = jax.eval_shape(learner.init, jax.random.PRNGKey(0), hp, data)
    lowered = jax.jit(lambda st, h, d: learner.run(st, h, d, 1)[0].params).lower(state, hp, data)
    try:
        flops = (lowered.cost_analysis() or {}).get("flops")
    except Exception:  # noqa: BLE001 - a backend without a cost model
        return None
    return float(flops) if flops else None


def train_rate(encoder: str, size: int, repeats: int, grid: int = 1, dtype: str = "float32", batch: int = BATCH,
               scan_chunk: int = SCAN_CHUNK) -> tuple[float, float, str]:
    """(compile_s, model-updates/s, chunk) of `grid` configurations at `size`×`size` (vmapped if `grid > 1`)
    computing in `dtype`; `encoder` may name its normalisation, `"patch+group"`."""
    from ape_jax.learner import Data, Hparams, LearnerConfig, make_train, stack_hparams
    from ape_jax.pipeline.sweep import CPU_IMAGE_CHUNK, trains_sequentially

    encoder, norm = split_encoder(encoder)
    unroll = trains_sequentially((size, size, 3), encoder)
    chunk = CPU_IMAGE_CHUNK if unroll else scan_chunk
    cfg = LearnerConfig(obs_shape=(size, size, 3), action_dim=ACT, history=H, batch_size=batch, unroll=unroll,
                        encoder=encoder, encoder_norm=norm, dtype=dtype)
    rng = np.random.default_rng(0)
    n = 2_000
    data = Data(obs=jnp.asarray(rng.integers(0, 256, (n, size, size, 3), np.uint8)),
                action=jnp.asarray(rng.uniform(-1, 1, (n, ACT)), jnp.float32),
                t=jnp.asarray(np.arange(n) % 1000, jnp.int32), ape=jnp.ones(n, jnp.float32))
    learner = make_train(cfg)
    hp = stack_hparams([Hparams.make("step", thr=0.1, w=5.0, lr=2e-4 * (1 + i)) for i in range(grid)])
    keys = jax.random.split(jax.random.PRNGKey(0), grid)
    state = jax.jit(jax.vmap(learner.init, (0, 0, None)))(keys, hp, data)
    if grid == 1:  # one configuration's own program, as the sweep compiles it (no vmap)
        state, hp = jax.tree.map(lambda x: x[0], (state, hp))
        run = jax.jit(lambda s, h, d: learner.run(s, h, d, chunk)[0].params)
    else:
        run = jax.jit(jax.vmap(lambda s, h, d: learner.run(s, h, d, chunk)[0].params, (0, 0, None)))
    compile_s, steady_s, _ = time_jitted(run, state, hp, data, repeats=repeats)
    return compile_s, grid * chunk / steady_s, f"{chunk} {'unrolled' if unroll else 'scanned'}"


def eval_rate(size: int, encoder: str, policies: int, episodes: int, steps: int, repeats: int
              ) -> tuple[float, float]:
    """(compile_s, policy-steps/s) of the image evaluator on hopper at `size`×`size` with `encoder`'s policies."""
    import envs
    from ape_jax import evaluate
    from ape_jax.learner import LearnerConfig

    env = envs.make("hopper", obs="image", image_size=(size, size))
    encoder, norm = split_encoder(encoder)
    cfg = LearnerConfig(obs_shape=env.observation_shape, action_dim=env.action_size, history=H, encoder=encoder,
                        encoder_norm=norm)
    keys = jax.random.split(jax.random.PRNGKey(0), policies)
    params = jax.vmap(lambda k: cfg.model().init(k, jnp.zeros((1, size, size, 3 * H))))(keys)
    run = evaluate.make_evaluator(env, cfg, None, None, episodes, steps=steps)
    compile_s, steady_s, _ = time_jitted(run, params, jax.random.PRNGKey(1), repeats=repeats)
    return compile_s, policies * episodes * steps / steady_s


def table(args) -> str:
    cmd = (f"python -m experiments.bench_images --sizes {','.join(map(str, args.sizes))} --encoders "
           f"{','.join(args.encoders)} --dtype {','.join(args.dtype)} --batch {args.batch} --chunk {args.chunk} "
           f"--grid {args.grid} --policies {args.policies} --episodes {args.episodes} --repeats {args.repeats}"
           f"{' --no-eval' if args.no_eval else ''}")
    first = f"{split_encoder(args.encoders[0])[0]} {sized(args.encoders[0], args.sizes)[0]} {args.dtype[0]}"
    from experiments.bench_train import matmul_peak

    n = 8192 if jax.default_backend() == "gpu" else 2048
    peaks = {d: matmul_peak(args.repeats, (n,), getattr(jnp, d))[n] for d in args.dtype}
    print(f"matmul peak ({n}×{n}): " + ", ".join(f"{d} {p / 1e12:.2f} TFLOP/s" for d, p in peaks.items()),
          file=sys.stderr)
    lines = ["## Image policies: training and evaluation speed, memory", "", f"Command: `{cmd}`  ",
             f"Machine: {machine()}  ",
             f"Medians of {args.repeats} runs after a compiling call, batch {args.batch}, history {H}; each encoder "
             "trained as the sweep trains it on this backend (one configuration at a time in unrolled chunks, "
             "or vmapped in scanned chunks); a vmapped grid counts every configuration's updates; bfloat16: "
             "mixed precision (float32 parameters, optimiser and loss).", "",
             "GFLOP per update: XLA's count of one update's program (`update_flops`); TFLOP/s: that × "
             f"model-updates/s; the last but one column: that against the dtype's matmul peak measured in this run "
             f"({n}×{n} products: " + ", ".join(f"{d} {p / 1e12:.2f} TFLOP/s" for d, p in peaks.items()) + ").", "",
             f"| encoder | image | dtype | configurations | chunk | model-updates/s | ms per update | compile s | "
             f"GFLOP per update | TFLOP/s | of the peak | × {first} |",
             "|---|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    base = None
    for encoder in args.encoders:
        for size in sized(encoder, args.sizes):
            for dtype in args.dtype:
                for grid in sorted({1, args.grid}):
                    compile_s, rate, chunk = train_rate(encoder, size, args.repeats, grid, dtype, args.batch,
                                                        args.chunk)
                    base = base or rate
                    flops = update_flops(encoder, size, dtype, args.batch)
                    achieved = "—" if flops is None else f"{flops * rate / 1e12:.3f}"
                    share = "—" if flops is None else f"{flops * rate / peaks[dtype]:.1%}"
                    lines.append(f"| {encoder.partition('@')[0]} | {size}×{size} | {dtype} | "
                                 f"{grid if grid == 1 else f'{grid}, vmapped'} | {chunk} | {rate:,.2f} | "
                                 f"{1e3 / rate:,.1f} | {compile_s:.1f} | "
                                 f"{'—' if flops is None else f'{flops / 1e9:,.2f}'} | {achieved} | {share} | "
                                 f"{rate / base:.3f} |")
                    print(lines[-1], file=sys.stderr)
    lines.append("")
    for encoder in ([] if args.no_eval else args.encoders):
        size = sized(encoder, args.sizes)[0]
        compile_s, rate = eval_rate(size, encoder, args.policies, args.episodes, 200, args.repeats)
        lines += [f"Evaluation, hopper {size}×{size} ({encoder.partition('@')[0]} encoder, rendering in the jitted "
                  f"rollout, {args.policies} policies × {args.episodes} episodes × 200 steps): **{rate:,.0f}** "
                  f"policy-steps/s (compile {compile_s:.1f} s).", ""]
        print(lines[-2], file=sys.stderr)
    lines.append(f"Peak resident memory of this process: "
                 f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GB.")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.bench_images", description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=lambda s: [int(x) for x in s.split(",")], default=[32, 64],
                   help="image sides, comma list (default: 32,64; the first is also evaluated)")
    p.add_argument("--encoders", type=lambda s: s.split(","), default=["small", "patch"],
                   help="comma list of image encoders (`ape_jax.models.IMAGE_ENCODERS`), each with `+group` for "
                        "GroupNorm (`recipe.encoder_norm`) and `@SIZE` for its own image side in place of --sizes, "
                        "e.g. small,patch+group,drq@84 (default: small,patch); the first is the reference of the "
                        "last column; resnet18 takes seconds per update on a CPU, drq about one at 84x84")
    p.add_argument("--dtype", type=lambda s: s.split(","), default=["float32"],
                   help="comma list of the policies' arithmetic (`recipe.dtype`): float32, bfloat16 (default: float32)")
    p.add_argument("--batch", type=int, default=BATCH, help=f"minibatch rows per update (default: {BATCH})")
    p.add_argument("--chunk", type=int, default=SCAN_CHUNK,
                   help=f"iterations per call of a scanned chunk (default: {SCAN_CHUNK}); an unrolled one is the "
                        "sweep's CPU_IMAGE_CHUNK")
    p.add_argument("--no-eval", action="store_true", help="time training only (the evaluation compiles MJX)")
    p.add_argument("--grid", type=int, default=1,
                   help="also time this many configurations trained as one vmapped program (default: 1, none)")
    p.add_argument("--policies", type=int, default=3, help="policies evaluated at once")
    p.add_argument("--episodes", type=int, default=4, help="episodes per policy")
    p.add_argument("--repeats", type=int, default=3, help="timed runs; the median is reported")
    return run_benchmark(p, argv, ("--grid", "--policies", "--episodes", "--repeats", "--batch", "--chunk"), table,
                         SECTION,
                         check=_check)


def _check(args) -> str | None:
    from ape_jax import models
    from ape_jax.models import DTYPES, IMAGE_ENCODERS, NORMS

    if not args.sizes or min(args.sizes) < 8 or max(args.sizes) > 512:
        return f"--sizes must be image sides in [8, 512], got {args.sizes}"
    if bad := [d for d in args.dtype if d not in DTYPES]:
        return f"--dtype: unknown {bad}; valid: {', '.join(DTYPES)}"
    if "bfloat16" in args.dtype and (problem := models.bf16_problem()):
        return f"--dtype bfloat16: {problem}"
    try:
        own = [sized(e, args.sizes) for e in args.encoders]
    except ValueError:
        return f"--encoders: a size after @ must be an integer, got {args.encoders}"
    if any(not 8 <= s <= 512 for sizes in own for s in sizes):
        return f"--encoders: a size after @ must be an image side in [8, 512], got {args.encoders}"
    # "perception" needs a task's encoder file: `experiments.bench_perception` times it
    timed = [name for name in IMAGE_ENCODERS if name != "perception"]
    unknown = [e for e in args.encoders if split_encoder(e)[0] not in timed]
    if unknown:
        return f"--encoders: unknown {unknown}; valid: {', '.join(timed)}, each with +group"
    norms = [e for e in args.encoders if split_encoder(e)[1] not in NORMS or
             (split_encoder(e)[1] != "none" and split_encoder(e)[0] == "resnet18")]
    if norms:
        return f"--encoders: {norms}: the small and patch encoders take +{', +'.join(n for n in NORMS if n != 'none')}"
    small = [f"{e} at {s}x{s}" for e, sizes in zip(args.encoders, own) for s in sizes
             if s < IMAGE_ENCODERS[split_encoder(e)[0]].min_side]
    return (f"--encoders: {', '.join(small)}: smaller than the encoder takes "
            f"({', '.join(f'{n}: {c.min_side}' for n, c in IMAGE_ENCODERS.items() if c.min_side > 1)})"
            if small else None)


if __name__ == "__main__":
    sys.exit(main())
