"""The main job: `python -m experiments.sweep`.

The keyframe-weighting sweep (APE, the weighted-BC grid, evaluation) is built
in issue 4. Until then this entry point accepts the sweep's command line and
runs the environment layer the sweep stands on: a short batched rollout of
every environment (a uniform-random policy), printing compile time and
throughput, so a fresh install can be checked end to end.
"""

from __future__ import annotations

import argparse
import sys

from tqdm import tqdm

import envs
from experiments._timing import rollout_throughput

PRESETS = ("quick", "default", "paper")


def parse(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m experiments.sweep", description=__doc__.splitlines()[0])
    p.add_argument("--env", default=",".join((*envs.MUJOCO_TASKS, "toycar")),
                   help="an environment name, a comma list, or 'all' for every registered one "
                        "(default: the paper's three tasks and toycar; 'all' takes ~10 min on 2 cores, "
                        "Brax's pusher alone runs ~20 steps/s on CPU)")
    p.add_argument("--obs", default=None, help="observation mode (default: pos where supported, else the env's default)")
    p.add_argument("--preset", default="quick", choices=PRESETS)
    p.add_argument("--episodes", type=int, default=16, help="episodes per rollout (vmapped)")
    p.add_argument("--steps", type=int, default=100, help="steps per episode (scanned)")
    args = p.parse_args(argv)
    names = list(envs.names()) if args.env == "all" else [n.strip() for n in args.env.split(",") if n.strip()]
    unknown = [n for n in names if n not in envs.names()]
    if unknown or not names:
        p.error(f"unknown env {unknown or args.env!r}; valid: {', '.join(envs.names())} or 'all'")
    if args.obs is not None:
        bad = [n for n in names if args.obs not in envs.obs_modes(n)]
        if bad:
            p.error(f"--obs {args.obs!r} is not supported by {', '.join(bad)}")
    if args.episodes < 1 or args.steps < 1:
        p.error("--episodes and --steps must be >= 1")
    args.names = names
    return args


def main(argv=None) -> int:
    args = parse(argv)
    print("The keyframe-weighting sweep is not built yet (issue 4); running a short rollout of "
          f"{len(args.names)} environment(s): {args.episodes} episodes x {args.steps} steps, random actions.")
    rows = []
    for name in tqdm(args.names, desc="environments", unit="env"):
        obs = args.obs or ("pos" if "pos" in envs.obs_modes(name) else envs.default_obs(name))
        r = rollout_throughput(envs.make(name, obs=obs), args.episodes, args.steps, repeats=3)
        rows.append((name, obs, r))
        tqdm.write(f"{name:>26} ({obs:>5}): compile {r['compile_s']:5.1f} s, {r['steps_per_s']:>10,.0f} env steps/s")
    print(f"\n{'env':>26}  obs    compile s   env steps/s   mean return (random policy)")
    for name, obs, r in rows:
        print(f"{name:>26}  {obs:<5} {r['compile_s']:9.1f} {r['steps_per_s']:13,.0f}   {r['return_mean']:10.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
