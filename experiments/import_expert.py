"""Import an expert from a file: `python -m experiments.import_expert PATH --env hopper --name cs294`.

Reads a CS294/FCA policy pickle (with an unpickler that builds numpy arrays and
plain containers only) or a plain `.npz` MLP (the formats: `envs.experts.imported`),
checks that it reads the task's full observation and gives its actions,
measures its and a random policy's returns under `--protocols` (default: the
task's `mujoco-state` and `brax`; the same code path as `experiments.expert_references`),
and writes it, converted, with its card (source path, format, SHA-256, origin)
and references into the user's expert directory, `$APE_JAX_EXPERTS/<env>-<name>/`
(default: the cache directory's `experts/`), never into the repository.

Use it like a shipped variant: `python -m experiments.sweep --set protocol.expert=NAME`
(and `--set protocol.labels=raw` to train on its unbounded labels as FCA did).

Refused with one line and exit status 2, nothing written: a missing or unreadable
file (a folder, a truncated or corrupt pickle or .npz), a pickle that holds
anything but numpy arrays and plain containers, an `.npz` with missing layers,
layers that do not chain, an input size other than the task's full observation,
a name that is a shipped expert's, or an imported expert of that name from
another file (unless `--force`).
"""

from __future__ import annotations

import pathlib
import sys
import time

from experiments._cli import (Parser, add_compile_cache_flag, fail, interruptible, raise_if_interrupted, unreadable,
                             unwritable, use_compile_cache)

# Episodes of the expert and of a random policy per protocol: the whole import of a Hopper expert within two
# minutes on a 2-core CPU (mujoco-state's episodes are 2,000 steps at frame skip 1, brax's 1,000 at frame skip 4)
EPISODES = {"mujoco-state": 20, "brax": 10}
DEFAULT_EPISODES = 10


@interruptible("an expert is written only once measured, whole")
def main(argv=None) -> int:
    t0 = time.perf_counter()
    import envs
    from ape_jax import tasks
    from ape_jax.pipeline import presets
    from envs import experts
    from envs.experts import imported
    from experiments import expert_references

    p = Parser(prog="python -m experiments.import_expert", description=__doc__.splitlines()[0])
    p.add_argument("path", type=pathlib.Path, help="the expert's file: a CS294 pickle or an .npz MLP")
    p.add_argument("--env", default="hopper", help="the task it acts in (default: hopper)")
    p.add_argument("--name", required=True, help="its variant name: lowercase letters, digits and _ (e.g. cs294, "
                                                 "FCA's CS294 Hopper expert); "
                                                 "selected with --set protocol.expert=NAME")
    p.add_argument("--format", default="auto", choices=("auto", *imported.FORMATS),
                   help="the file's format (default: by its first bytes)")
    p.add_argument("--protocols", default=None,
                   help="comma-separated protocols to measure its references under (default: the task's "
                        "mujoco-state and brax)")
    p.add_argument("--episodes", type=int, default=None,
                   help=f"episodes of the expert and of a random policy per protocol (default: {EPISODES})")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--force", action="store_true", help="replace an imported expert of that name from another file")
    add_compile_cache_flag(p)
    args = p.parse_args(argv)
    use_compile_cache(args)
    task = tasks.get(args.env)
    if args.env not in envs.names() or not task.has_card:
        fail(p, f"--env {args.env!r}: experts are imported for MuJoCo tasks; valid: "
                f"{', '.join(n for n in envs.names() if tasks.get(n).has_card)}")
    if not imported.NAME.fullmatch(args.name):
        fail(p, f"--name {args.name!r} must be lowercase letters, digits and _ (e.g. cs294)")
    if why := unreadable(args.path, "an expert file (a CS294 pickle or an .npz MLP)"):
        fail(p, why)
    full = f"{args.env}-{args.name}"
    if full in experts.available():
        fail(p, f"--name {args.name!r}: {full} is a shipped expert (envs/experts/{full}); pick another name")
    names = args.protocols.split(",") if args.protocols else [task.protocol(None, "full").name, "brax"]
    try:
        protocols = {}
        for n in names:
            proto = task.protocol(presets.current_protocol(n.strip()), "full")
            protocols.setdefault(proto.reference or proto.name, task.protocol(proto.reference or proto.name, "full"))
    except ValueError as e:
        fail(p, f"--protocols: {e}")
    if args.episodes is not None and args.episodes < 1:
        fail(p, f"--episodes must be >= 1, got {args.episodes}")
    why = unwritable(imported.root())
    if why:
        fail(p, f"the expert directory {imported.root()} cannot be written: {why} (set APE_JAX_EXPERTS)")

    env = envs.make(args.env, obs="full")
    try:
        converted = imported.read(args.path, args.format, env.action_size)
        fmt = imported.detect_format(args.path) if args.format == "auto" else args.format
        imported.check_fits(converted, args.env, env.observation_shape[0], env.action_size, str(args.path))
    except imported.ImportError_ as e:
        fail(p, str(e))
    source = imported.source_info(args.path, fmt)
    existing = imported.root() / full / experts.CARD
    if existing.is_file() and not args.force:
        try:
            old = experts.card(full).get("source", {}).get("sha256")
        except experts.ExpertError:
            old = None  # an unreadable card: replaced only when asked
        if old != source["sha256"]:
            fail(p, f"{full} is imported already from another file (SHA-256 {str(old)[:12]}…, now "
                    f"{source['sha256'][:12]}…); pick another --name, or pass --force to replace it")
    if source.get("origin"):
        print(f"recognised by its SHA-256: {source['title']} ({source['origin']}); not redistributable here")

    import jax.numpy as jnp

    params = {k: [jnp.asarray(x) for x in v] if isinstance(v, list) else jnp.asarray(v)
              for k, v in converted.params.items()}
    policy = experts.policy_from_params(params, converted.activation, converted.head)
    command = " ".join(["python", "-m", "experiments.import_expert", *(sys.argv[1:] if argv is None else argv)])
    references = {}
    for name, proto in protocols.items():
        episodes = args.episodes or EPISODES.get(name, DEFAULT_EPISODES)
        references[name] = expert_references.measure(args.env, proto, policy, episodes, args.seed, command)
        r = references[name]
        print(f"{name}: expert {r['return_mean']:,.1f} ± {r['return_std']:,.1f}, random policy "
              f"{r['random_return_mean']:,.1f} over {episodes} episodes each ({r['seconds']:.0f} s)")
    card = imported.card_for(args.env, args.name, converted, source, command)
    raise_if_interrupted()   # a Ctrl-C whose exception was ignored (a gc callback): nothing written
    target = imported.install(args.env, args.name, converted, card, references)
    print(f"imported {full} ({fmt}, SHA-256 {source['sha256']}): {converted.obs_size} inputs, hidden "
          f"{converted.hidden} {converted.activation}, {converted.action_size} actions ({converted.head} head) in "
          f"{time.perf_counter() - t0:.0f} s; wrote {target}\n"
          f"use it with --set protocol.expert={args.name}"
          + (" (add --set protocol.labels=raw for its labels as it gives them)" if converted.head == "linear" else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
