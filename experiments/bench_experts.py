"""Experts and demonstration collection: the shipped experts' cards, and collection throughput.

    python -m experiments.bench_experts                        # print the tables
    python -m experiments.bench_experts --write docs/speed.md  # also replace its section

The expert table is read from the cards written by `experiments.train_expert`
(returns measured there over 100 episodes of `envs.make(env, obs="full")`).
Collection throughput is `ape_jax.pipeline.collect`'s jitted batch collector (expert
policy, clean labels, simulator state recorded), median of `--repeats` runs
after a separate compiling call, counting only the steps inside episodes.
"""

from __future__ import annotations

import sys

import jax
import numpy as np

import envs
from ape_jax import tasks
from ape_jax.pipeline import collect
from envs import experts
from experiments._cli import Parser
from experiments._timing import machine, run_benchmark, time_jitted

SECTION = "bench_experts"
CASES = (("hopper", "pos", {}), ("hopper", "full", {}), ("hopper", "image", {"image_size": 64}),
         ("halfcheetah", "pos", {}), ("walker2d", "pos", {}),
         *((name, obs, kw) for name in tasks.sweepable() if tasks.get(name).expert == "rule-based"
           for obs, kw in (("full", {}), ("image", {"image_size": 128}))))


def expert_rows() -> list[str]:
    rows = ["| env | algorithm | env steps (best policy / trained) | wall time | return, 100 episodes | "
            "random policy | target | hardware |", "|---|---|---:|---:|---:|---:|---:|---|"]
    for name in envs.MUJOCO_TASKS:
        try:
            c = experts.card(name)
        except experts.ExpertError:
            rows.append(f"| {name} | *not trained yet* | | | | | | |")
            continue
        target = c.get("target_return")
        met = "" if target is None else (" ✓" if c["return_mean"] >= target else " ✗ (short)")
        rows.append(
            f"| {name} | SAC | {c['env_steps']:,} / {c['env_steps_trained']:,} | {c['wall_s'] / 60:.0f} min | "
            f"{c['return_mean']:,.0f} ± {c['return_std']:,.0f} | {c['random_return_mean']:,.0f} ± "
            f"{c['random_return_std']:,.0f} | {target:,.0f}{met} | {c['hardware']} |")
    return rows


def collection_row(name: str, obs: str, overrides: dict, batch: int, repeats: int) -> str | None:
    env = envs.make(name, obs=obs, **overrides)
    try:
        expert, _ = collect.expert_for(env)
    except experts.ExpertError:
        return None
    run = collect.make_batch_collector(env, expert, batch)
    keys = iter(jax.random.split(jax.random.PRNGKey(0), repeats + 1))
    compile_s, steady_s, traj = time_jitted(lambda: run(next(keys)), repeats=repeats)
    steps = float(np.asarray(traj.valid).sum())
    frames = f"{steps / steady_s:,.0f}" if obs == "image" else "–"
    size = f" {overrides['image_size']}²" if "image_size" in overrides else ""
    return (f"| {name} ({obs}{size}) | {batch} × {env.episode_length} | {steps / batch:,.0f} | "
            f"{steps / steady_s:,.0f} | {frames} | {compile_s:.1f} |")


def table(args) -> str:
    lines = ["## Experts", "", "From the experts' cards (`envs/experts/<env>/card.json`), written by "
             "`python -m experiments.train_expert --env <env>`; returns over 100 episodes of 1000 steps, "
             "deterministic policy, full observation. Training: `ape_jax/experts/sac.py` with the settings in "
             "`experiments/train_expert.py` (update-to-data 0.5, batch 256, 256×256 MLPs), stopped once the "
             "16-episode evaluation return passed 1.1× the target; the step count is when the best policy was "
             "seen. Wall time is the sum of training epochs and evaluations, measured while other work shared "
             "the 2 cores.", "", *expert_rows(), "",
             "### Demonstration collection", "",
             f"Command: `python -m experiments.bench_experts --batch {args.batch} --repeats {args.repeats}`  ",
             f"Machine: {machine()}  ",
             f"Median of {args.repeats} runs after one compiling call (compile time apart); one run collects "
             f"`batch` expert episodes under jit (vmapped, scanned over the episode length) with labels and "
             "simulator state. Transitions/s counts steps inside episodes only.", "",
             "| env (obs) | episodes × max steps | mean episode length | transitions/s | frames/s | compile s |",
             "|---|---:|---:|---:|---:|---:|"]
    for name, obs, overrides in CASES:
        row = collection_row(name, obs, overrides, args.batch, args.repeats)
        lines.append(row or f"| {name} ({obs}) | no expert yet | | | | |")
        print(lines[-1], file=sys.stderr)
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.bench_experts", description=__doc__.splitlines()[0])
    p.add_argument("--batch", type=int, default=16, help="episodes collected per jitted call")
    p.add_argument("--repeats", type=int, default=3, help="timed runs; the median is reported")
    return run_benchmark(p, argv, ("--batch", "--repeats"), table, SECTION)


if __name__ == "__main__":
    sys.exit(main())
