"""Timing helpers shared by the entry points: compile time apart from steady state."""

from __future__ import annotations

import os
import statistics
import time
from typing import Any
from collections.abc import Callable

import jax


def time_jitted(fn: Callable, *args: Any, repeats: int = 5) -> tuple[float, float, Any]:
    """Times a jitted function: first call (compile + one run), then the median of `repeats` runs.

    Returns:
      (compile_s, steady_s, output): `compile_s` is the first call minus one
      steady-state run, `steady_s` the median over `repeats` runs; every clock
      stops after `block_until_ready`.
    """
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        runs.append(time.perf_counter() - t0)
    steady = statistics.median(runs)
    return max(first - steady, 0.0), steady, out


def rollout_throughput(env, batch: int, steps: int, repeats: int) -> dict:
    """Control steps/s of `envs.rollout` with a uniform-random policy.

    The policy reads the observation (a negligible term in its action), as a
    real policy does: otherwise XLA removes observation work that nothing
    consumes, such as ToyCar's rendering, and the figure would be fiction.

    Returns:
      `{"compile_s", "steps_per_s", "return_mean"}`; the rollout is vmapped
      over `batch` episodes and scanned over `steps`.
    """
    import jax.numpy as jnp

    import envs

    low, high = env.action_bounds
    low, high = jnp.maximum(low, -1.0), jnp.minimum(high, 1.0)

    def act(params, state, key):
        seen = 1e-12 * jnp.mean(state.obs.astype(jnp.float32))
        return jax.random.uniform(key, low.shape, minval=low, maxval=high) + seen

    policy = envs.stateless(act)
    run = jax.jit(lambda k: envs.rollout(env, policy, None, k, batch, steps).returns)
    compile_s, steady_s, returns = time_jitted(run, jax.random.PRNGKey(0), repeats=repeats)
    return {"compile_s": compile_s, "steps_per_s": batch * steps / steady_s, "return_mean": float(returns.mean())}


def machine() -> str:
    """The CPU, core count, and JAX and MuJoCo versions, for benchmark headers."""
    from importlib.metadata import version

    from experiments._provenance import machine as cpu

    return f"{cpu()}, jax {jax.__version__} ({jax.default_backend()}), mujoco {version('mujoco')}"


def splice_section(old: str | None, text: str, name: str) -> str:
    """`old` with the section between `<!-- NAME:start -->` and `<!-- NAME:end -->` replaced by `text`, or
    with the section appended; None (no file yet) starts a new `# Benchmarks` file."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    block = f"{start}\n{text}{end}\n"
    old = "# Benchmarks\n\n" if old is None else old
    if start in old and end in old:
        return old[: old.index(start)] + block + old[old.index(end) + len(end) + 1 :]
    return old.rstrip("\n") + "\n\n" + block


def write_text_atomic(path: str, text: str) -> None:
    """Writes `text` to `path` through a temporary file and a rename, so a reader sees the old or the new file."""
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def write_section(path: str, text: str, name: str = "bench_envs") -> None:
    """Replaces the section of `path` between `<!-- NAME:start -->` and `<!-- NAME:end -->`
    (or appends it), atomically."""
    write_text_atomic(path, splice_section(open(path).read() if os.path.exists(path) else None, text, name))


def run_benchmark(parser, argv, counts: tuple[str, ...], table, section: str,
                  check: Callable[[Any], str | None] | None = None) -> int:
    """The shared tail of the `bench_*` entry points.

    Adds `--write`, parses `argv`, refuses (exit 2, before anything is timed)
    counts below 1, a `--write` file that cannot be written and whatever
    `check(args)` names (it returns the message, or None), prints
    `table(args)` and, with `--write FILE`, replaces the section `section` of FILE.
    """
    from experiments._cli import unwritable_file

    parser.add_argument("--write", metavar="docs/speed.md", help="replace the section in this file")
    args = parser.parse_args(argv)
    if min(getattr(args, c.lstrip("-").replace("-", "_")) for c in counts) < 1:
        parser.error(f"{', '.join(counts)} must be >= 1")
    if args.write:
        why = unwritable_file(args.write)
        if why is None and os.path.exists(args.write):
            try:
                open(args.write).read()
            except (OSError, UnicodeDecodeError) as e:
                why = f"it cannot be read as text ({e})"
        if why:
            parser.error(f"--write {args.write}: cannot write there: {why}")
    why = check(args) if check is not None else None
    if why:
        parser.error(why)
    text = table(args)
    print(text)
    if args.write:
        write_section(args.write, text, section)
        print(f"wrote the section to {args.write}")
    return 0
