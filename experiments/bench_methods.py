"""Each method's time per policy in a real sweep, beside BC-SO's: `python -m experiments.bench_methods`.

    python -m experiments.bench_methods --env toytown --obs pos --write docs/speed.md

For each method, one seed of the preset (`--preset`, default `default`) is swept on its own (`experiments.sweep`
in a fresh process, demonstrations from the cache, the copycat diagnostics off), `--repeats` times, the methods
interleaved so a change in the machine's load falls on all of them. Each sweep's own `timing` gives its compile,
training and evaluation seconds; the table shows their medians per method and the method's training and
evaluation time over BC-SO's (the same repeats; a ratio from runs seconds apart on one machine). The first call
per method also pays its compile, reported apart. Collection is excluded: the demonstrations are collected once,
before the first timed sweep.
"""

from __future__ import annotations

import json
import pathlib
import statistics
import subprocess
import sys
import tempfile

from experiments._timing import run_benchmark

METHODS = "bc-so,bc-oh,ours-step,fca,history-dropout,dagger,boosting,rap,palr,mine,bc-full"
SECTION = "bench_methods"


def _sweep(args, method: str, out: pathlib.Path) -> dict:
    """One sweep of `method` (one seed, no diagnostics) into `out`; its results' `timing`."""
    cmd = [sys.executable, "-m", "experiments.sweep", "--env", args.env, "--obs", args.obs, "--preset", args.preset,
           "--methods", method, "--seeds", "1", "--set", "budget.probe_steps=0", "--quiet", "--yes", "--out",
           str(out), *(["--protocol", args.protocol] if args.protocol else [])]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"python -m experiments.bench_methods: error: the sweep of {method} failed "
                         f"(exit {done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    return json.loads((out / "results.json").read_text())["timing"]


def measure(args) -> dict[str, list[dict]]:
    """`{method: [timing of each repeat]}`, the methods interleaved within each repeat."""
    methods = args.methods.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        _sweep(args, methods[0], pathlib.Path(tmp) / "warm")  # collects (or finds) the demonstrations once
        out: dict[str, list[dict]] = {m: [] for m in methods}
        for r in range(args.repeats):
            for m in methods:
                out[m].append(_sweep(args, m, pathlib.Path(tmp) / f"{m}-{r}"))
    return out


def table(args) -> str:
    times = measure(args)
    med = {m: {k: statistics.median(t[k] for t in ts) for k in ("compile_s", "train_s", "eval_s")}
           for m, ts in times.items()}
    base = med.get("bc-so")
    from ape_jax.pipeline.provenance import machine
    lines = [f"Each method alone, one seed of `{args.env}` `{args.obs}` at preset `{args.preset}`"
             + (f", protocol `{args.protocol}`" if args.protocol else "") + f": medians of {args.repeats} sweeps "
             f"(`python -m experiments.bench_methods --env {args.env} --obs {args.obs} --preset {args.preset}"
             f" --repeats {args.repeats}`; {machine()}, other work beside it). Training and "
             "evaluation of the one policy; × BC-SO: the method's time over BC-SO's.", "",
             "| method | compile, s | train, s | evaluate, s | train × BC-SO | evaluate × BC-SO |",
             "|---|---:|---:|---:|---:|---:|"]
    for m, t in med.items():
        ratio = (lambda k: f"{t[k] / base[k]:.2f}" if base and base[k] > 0 else "-")  # noqa: E731
        lines.append(f"| {m} | {t['compile_s']:.1f} | {t['train_s']:.1f} | {t['eval_s']:.1f} | {ratio('train_s')} | "
                     f"{ratio('eval_s')} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    from experiments._cli import Parser

    p = Parser(prog="python -m experiments.bench_methods", description=__doc__.splitlines()[0])
    p.add_argument("--env", default="toytown")
    p.add_argument("--obs", default="pos")
    p.add_argument("--protocol", default=None, help="the sweep's --protocol (default: the task's for --obs)")
    p.add_argument("--preset", default="default")
    p.add_argument("--methods", default=METHODS, help=f"comma-separated, BC-SO first for the ratios ({METHODS})")
    p.add_argument("--repeats", type=int, default=2, help="sweeps per method; the median is reported")
    return run_benchmark(p, argv, ("--repeats",), table, SECTION, check=_check)


def _check(args) -> str | None:
    """Why the benchmark cannot run as asked (before anything is timed), or None."""
    import envs
    from ape_jax import methods

    unknown = [m for m in args.methods.split(",") if m not in methods.names()]
    if unknown:
        return f"--methods: unknown {unknown}; valid: {', '.join(methods.names())}"
    if args.env not in envs.names() and args.env not in envs.brax_env.brax_names():
        return f"--env {args.env!r}: no such task; valid: {', '.join(envs.names())} or a Brax environment"
    if args.obs not in envs.obs_modes(args.env):
        return f"--obs {args.obs!r} is not supported by {args.env}; valid: {', '.join(envs.obs_modes(args.env))}"
    return None


if __name__ == "__main__":
    sys.exit(main())
