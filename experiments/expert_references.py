"""Measure an expert's reference returns under a protocol: `python -m experiments.expert_references --env hopper`.

`normalized = 100 · (R − R_random) / (R_expert − R_random)` needs the expert's
and a random policy's returns in the setting the policies are evaluated in.
The card (`envs/experts/<env>/card.json`) holds them for the setting the expert
was trained at (`brax`); this measures them under another protocol (default
`fca`: frame skip 1, 500 standard steps of simulated time, rewards on the
standard-step scale) over `--episodes` episodes each, and writes them into
`envs/experts/<env>/references.json` (atomically; other protocols' entries
are kept); `--expert ppo` measures the variant shipped beside it,
`envs/experts/<env>-ppo/`. The card itself is left as it is, so the datasets
and checkpoints named by its hash stay valid.
"""

from __future__ import annotations

import json
import sys
import time

from experiments._cli import Parser, fail


def main(argv=None) -> int:
    import jax

    import envs
    from ape_jax import tasks
    from ape_jax.pipeline.data import write_atomic
    from envs import experts
    from experiments._measure import expert_and_random_returns
    from experiments._provenance import machine

    p = Parser(prog="python -m experiments.expert_references", description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help=f"an env with a shipped expert: {', '.join(experts.available())}")
    p.add_argument("--protocol", default="fca", help=f"one of {', '.join(n for n in tasks.PROTOCOLS if n != 'brax')}")
    p.add_argument("--episodes", type=int, default=100, help="episodes of the expert and of a random policy")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--expert", default=None, metavar="VARIANT",
                   help="an expert shipped beside the task's own, envs/experts/<env>-VARIANT (e.g. ppo)")
    args = p.parse_args(argv)
    name = args.env if args.expert is None else f"{args.env}-{args.expert}"
    if args.env not in envs.names() or name not in experts.available():
        fail(p, f"no shipped expert {name!r}; valid: {', '.join(experts.available())}")
    if args.protocol not in tasks.PROTOCOLS or args.protocol == "brax":
        fail(p, f"unknown protocol {args.protocol!r}; valid: {', '.join(n for n in tasks.PROTOCOLS if n != 'brax')} "
                "('brax' is the card's own setting)")
    if args.episodes < 1:
        fail(p, f"--episodes must be >= 1, got {args.episodes}")
    try:
        protocol = tasks.get(args.env).protocol(args.protocol, "full")
        policy = experts.load(name)
    except (ValueError, experts.ExpertError) as e:
        fail(p, str(e))
    standard = envs.brax_env.default_frame_skip(args.env)
    env = envs.make(args.env, obs="full", **protocol.env_overrides(standard))
    print(f"{name} under {args.protocol}: frame skip {env.frame_skip}, {env.episode_length:,} steps per episode, "
          f"reward scale {env.config.reward_scale:g}; {args.episodes} episodes each of the expert and a random policy")
    t0 = time.perf_counter()
    measured = expert_and_random_returns(env, policy, args.episodes, jax.random.PRNGKey(args.seed))
    seconds = time.perf_counter() - t0
    entry = {**measured, "protocol": protocol.settings(standard), "seed": args.seed,
             "command": " ".join(["python", "-m", "experiments.expert_references", *(sys.argv[1:] if argv is None
                                                                                     else argv)]),
             "seconds": round(seconds, 1), "hardware": machine(), "jax": jax.__version__}
    path = experts.directory(name) / experts.REFERENCES
    refs = json.loads(path.read_text()) if path.is_file() else {}
    refs[args.protocol] = entry
    write_atomic(path, lambda f: f.write((json.dumps(refs, indent=2, sort_keys=True) + "\n").encode()))
    print(f"expert {measured['return_mean']:,.1f} ± {measured['return_std']:,.1f}, random policy "
          f"{measured['random_return_mean']:,.1f} ({seconds:.0f} s); wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
