"""Measure an expert's reference returns under a protocol: `python -m experiments.expert_references --env hopper`.

`normalized = 100 · (R − R_random) / (R_expert − R_random)` needs the expert's
and a random policy's returns in the setting the policies are evaluated in.
The card (`envs/experts/<env>/card.json`) holds them for the setting the expert
was trained at (`brax`); this measures them under another protocol (default
`mujoco-state`: frame skip 1, 500 standard steps of simulated time, rewards on the
standard-step scale) over `--episodes` episodes each, and writes them into
`envs/experts/<env>/references.json` (atomically; other protocols' entries
are kept); `--expert ppo` measures the variant shipped beside it,
`envs/experts/<env>-ppo/`, and `--expert NAME` an imported one
(`experiments.import_expert`, whose references all live in its references.json,
`brax` included). The card itself is left as it is, so the datasets
and checkpoints named by its hash stay valid. The expert's action is clipped to
the action bounds before the environment steps (an unbounded Gaussian mean
otherwise pays a control cost for torque it never applies).
"""

from __future__ import annotations

import json
import pathlib
import sys
import time
from collections.abc import Callable

from experiments._cli import Parser, fail


def returns(env, policy: Callable, num_episodes: int, key, batch: int = 100) -> tuple:
    """Episode returns of `policy` (`full obs [D] -> action [A]`, clipped to the action bounds) and of a random
    policy, `([num_episodes], [num_episodes])` float32: both in one compiled program (the rollouts of one vmapped
    over the two; compiling dominates a measurement on a CPU), with the keys `experiments._measure.
    expert_and_random_returns` gives each, so the numbers are the ones it measures."""
    import jax
    import jax.numpy as jnp

    import envs
    from envs import experts
    from experiments._measure import random_policy

    act, rand = experts.executed(policy, env.action_bounds), random_policy(env)

    def mixed(is_expert, state, key):
        return jnp.where(is_expert, act(env.expert_observation(state)), rand.act(None, (), state, key)[0])

    both = envs.stateless(mixed)
    n = min(batch, num_episodes)
    run = jax.jit(jax.vmap(lambda flag, k: envs.rollout(env, both, flag, k, n).returns))
    key_expert, key_random = jax.random.split(key)
    out = [run(jnp.array([True, False]), jnp.stack([jax.random.fold_in(key_expert, i),
                                                    jax.random.fold_in(key_random, i)]))
           for i in range(-(-num_episodes // batch))]
    out = jnp.concatenate(out, axis=1)[:, :num_episodes]
    return out[0], out[1]


def measure(env_name: str, protocol, policy: Callable, episodes: int, seed: int, command: str) -> dict:
    """The references of `policy` (`full obs [D] -> action [A]`, clipped here to the action bounds) and of a random
    policy under `protocol` (an `ape_jax.tasks.Protocol`): `return_mean`, `return_std`, `random_return_mean`,
    `random_return_std`, `episodes`, and how they were measured (protocol settings, seed, command, seconds,
    hardware, jax)."""
    import jax

    import envs
    from experiments._provenance import machine

    standard = envs.brax_env.default_frame_skip(env_name)
    env = envs.make(env_name, obs="full", **protocol.env_overrides(standard))
    t0 = time.perf_counter()
    expert, random = returns(env, policy, episodes, jax.random.PRNGKey(seed))
    return {"episodes": episodes, "return_mean": float(expert.mean()), "return_std": float(expert.std()),
            "random_return_mean": float(random.mean()), "random_return_std": float(random.std()),
            "protocol": protocol.settings(standard), "seed": seed, "command": command,
            "seconds": round(time.perf_counter() - t0, 1), "hardware": machine(), "jax": jax.__version__}


def record(directory: pathlib.Path, entries: dict[str, dict]) -> pathlib.Path:
    """Writes `entries` (`{protocol: measure(...)}`) into `directory/references.json`, atomically, keeping the
    other protocols' entries; returns the file."""
    from ape_jax.pipeline.data import write_atomic
    from envs import experts

    path = pathlib.Path(directory) / experts.REFERENCES
    refs = json.loads(path.read_text()) if path.is_file() else {}
    refs.update(entries)
    write_atomic(path, lambda f: f.write((json.dumps(refs, indent=2, sort_keys=True) + "\n").encode()))
    return path


def main(argv=None) -> int:
    import envs
    from ape_jax import tasks
    from ape_jax.pipeline import presets
    from envs import experts

    p = Parser(prog="python -m experiments.expert_references", description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help=f"an env with a shipped expert: {', '.join(experts.available())}")
    p.add_argument("--protocol", default=tasks.STATE, help=f"one of {', '.join(tasks.PROTOCOLS)} ('brax': imported "
                                                     "experts only; a shipped card holds it)")
    p.add_argument("--episodes", type=int, default=100, help="episodes of the expert and of a random policy")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--expert", default=None, metavar="VARIANT",
                   help="an expert shipped beside the task's own, envs/experts/<env>-VARIANT (e.g. ppo), or an "
                        "imported one (experiments.import_expert --name VARIANT)")
    args = p.parse_args(argv)
    name = args.env if args.expert is None else f"{args.env}-{args.expert}"
    known = (*experts.available(), *experts.imported_names())
    if args.env not in envs.names() or name not in known:
        fail(p, f"no shipped or imported expert {name!r}; valid: {', '.join(known)}")
    args.protocol = presets.current_protocol(args.protocol)
    if args.protocol not in tasks.PROTOCOLS or (args.protocol == "brax" and not experts.is_imported(name)):
        fail(p, f"unknown protocol {args.protocol!r}; valid: {', '.join(n for n in tasks.PROTOCOLS if n != 'brax')} "
                "('brax' is a shipped card's own setting)")
    if args.episodes < 1:
        fail(p, f"--episodes must be >= 1, got {args.episodes}")
    try:
        protocol = tasks.get(args.env).protocol(args.protocol, "full")
        policy = experts.load(name)
    except (ValueError, experts.ExpertError) as e:
        fail(p, str(e))
    command = " ".join(["python", "-m", "experiments.expert_references", *(sys.argv[1:] if argv is None else argv)])
    print(f"{name} under {args.protocol}: {args.episodes} episodes each of the expert and a random policy")
    entry = measure(args.env, protocol, policy, args.episodes, args.seed, command)
    path = record(experts.directory(name), {args.protocol: entry})
    print(f"expert {entry['return_mean']:,.1f} ± {entry['return_std']:,.1f}, random policy "
          f"{entry['random_return_mean']:,.1f} ({entry['seconds']:.0f} s); wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
