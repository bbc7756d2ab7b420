"""Which of the encoder's readings break driving: `python -m experiments.perception_drive`.

The expert drives ToyTown's held-out layouts (the `nocrash` protocol's evaluation settings) acting on its full state,
with some of the one-frame features replaced by what the shipped perception encoder reads from the camera frame
(`ape_jax.perception`, its read-out): none (the expert as it is), each group of features alone (the ego's speed; the
lane; the stop line and its light; the car ahead; the pedestrian; the blocked junction), then all of them. Where the
expert itself crashes on a group's readings, no imitator trained on the encoder's output can drive well, whatever the
held-out `1 − R²` says: that group's accuracy is what would lift the gate.

Writes `--out` (default `results/exploratory/toytown-perception-drive.json`): per variant, success, collisions (by
kind), stuck and average speed over `--episodes` episodes, and the command.
"""

from __future__ import annotations

import json
import pathlib
import sys

from experiments._cli import Parser, fail, interruptible, unwritable_file

ROOT = pathlib.Path(__file__).resolve().parents[1]
GROUPS = {
    "speed": ("speed",),
    "lane": ("lane_offset", "heading_error", "lane_x4", "lane_y4", "lane_x8", "lane_y8", "lane_x12", "lane_y12",
             "lane_x16", "lane_y16", "curvature_ahead"),
    "stop line and light": ("stop_gap", "light_green", "light_amber", "light_red"),
    "car ahead": ("lead_gap",),
    "pedestrian": ("ped_gap", "ped_offset"),
    "junction": ("junction_blocked",),
}


def measure(episodes: int, protocol: str, encoder_path: str = "task", seed: int = 0) -> list[dict]:
    import jax
    import jax.numpy as jnp
    import numpy as np

    import envs
    from ape_jax import perception, tasks
    from ape_jax.pipeline.setup import Setup
    from envs.toytown_expert import FEATURES

    setup = Setup.resolve("toytown", "image", tasks.get("toytown").protocol(protocol, "image"))
    env = envs.make("toytown", obs="image", **setup.evaluation)
    encoder = perception.resolve("toytown", encoder_path)
    perception.check_sweep(encoder, envs.make("toytown", obs="image", **setup.collection))
    read = perception.seeing(encoder, "readout")
    targets = list(encoder.card["targets"])
    rows = []
    for name, group in [("none", ()), *GROUPS.items(), ("all", tuple(t for t in targets if t in FEATURES))]:
        idx_full = jnp.array([FEATURES.index(f) for f in group], jnp.int32)
        idx_read = jnp.array([targets.index(f) for f in group], jnp.int32)

        def act(params, state, key, idx_full=idx_full, idx_read=idx_read):
            full = env.expert_observation(state)
            if idx_full.size:
                full = full.at[idx_full].set(read(state.obs)[idx_read])
            low, high = env.action_bounds
            return jnp.clip(env.expert(full), low, high)

        run = jax.jit(lambda k, act=act: envs.rollout(env, envs.stateless(act), None, k, episodes,
                                                       record=env.sim_state))
        traj = run(jax.random.PRNGKey(seed))
        metrics = jax.vmap(env.episode_metrics)(traj.extra, traj.final, traj.valid)
        rows.append({"replaced": name, "features": list(group),
                     **{k: float(np.mean(v)) for k, v in metrics.items()}})
        print(f"  {name:<20} success {100 * rows[-1]['success']:5.1f}%  collisions {rows[-1]['collisions']:.2f}  "
              f"speed {rows[-1]['avg_speed']:.2f} m/s", file=sys.stderr)
    return rows


def parse(argv=None):
    p = Parser(prog="python -m experiments.perception_drive", description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=50, help="held-out episodes per variant (default 50)")
    p.add_argument("--protocol", default="nocrash", choices=("nocrash", "nocrash-nospeed"))
    p.add_argument("--encoder", default="task", help="the encoder file (default: the shipped one, task)")
    p.add_argument("--out", type=pathlib.Path,
                   default=ROOT / "results" / "exploratory" / "toytown-perception-drive.json")
    args = p.parse_args(argv)
    if args.episodes < 1:
        fail(p, f"--episodes must be >= 1, got {args.episodes}")
    if (why := unwritable_file(args.out)) is not None:
        fail(p, why)
    return args


def perception_describe(path: str) -> dict:
    from ape_jax import perception

    return perception.resolve("toytown", path).describe()


@interruptible("nothing was written")
def main(argv=None) -> int:
    args = parse(argv)
    from experiments._provenance import system

    rows = measure(args.episodes, args.protocol, args.encoder)
    given = argv if argv is not None else sys.argv[1:]
    record = {"command": ["python", "-m", "experiments.perception_drive", *given],
              "env": "toytown", "protocol": args.protocol, "episodes": args.episodes, "rows": rows,
              "encoder": perception_describe(args.encoder),
              "system": system()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
