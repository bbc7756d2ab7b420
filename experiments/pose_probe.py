"""What an image policy's encoder can read from the frames: `python -m experiments.pose_probe`.

    python -m experiments.pose_probe --env hopper --image-size 32x32 --targets pose,velocity
    python -m experiments.pose_probe --env hopper --targets action --train-episodes 5,10,20 --history 2
    python -m experiments.pose_probe --env hopper --targets action --history 2 --obs pos   # BC-OH from the state

Why image behavioural cloning fails, measured with the sweep's own image network trained
from scratch, supervised, on the sweep's demonstrations (the `brax` protocol's image demonstrations, split by
episode as the sweep splits them; collected and cached as the sweep does). The network is
`LearnerConfig.model()` (`--encoder`, `--set recipe.*`), its output layer as wide as the targets:

- `pose`: the true `qpos` without the root's x (height, angles), what a frame shows;
- `velocity`: the true `qvel`, what the difference of two frames shows (`--history 2`);
- `action`: the expert's action, i.e. BC itself (unweighted, the sweep's BC-OH with `--history 2`).

`--obs pos` reads the true pose instead of frames (the sweep's state observations and the `mlp` recipe's
network): the reference, e.g. BC's `1 − R²` from the state against BC's from the frames.

Targets are standardised per dimension on the training rows, so the loss is the mean of their MSEs and a
constant prediction scores 1. For each target group the tool reports `1 − R²` (the held-out MSE over the
target's variance, averaged over its dimensions) on the training rows and on the validation episodes, at the
iterations of `--points`; for `action` also the BC loss on the sweep's scale (squared error summed over action
dimensions). `1 − R²` near 0 on the validation episodes: the encoder reads it at this image size; near 1: it
does not. `--train-episodes` trains on the first N training episodes only (the loss against the number of
demonstrations: falling with N means more demonstrations would help).

Optimisation is the recipe's (Adam at `recipe.lr`, batch `recipe.batch_size`, ×0.1 at a third and two thirds
of the run). It writes one JSON file (`--out`) with every number and the command, and prints a table.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time
from typing import TYPE_CHECKING

from experiments._cli import Parser, data_directory, fail, unwritable_file

if TYPE_CHECKING:
    import numpy as np

PROG = "python -m experiments.pose_probe"
TARGETS = ("pose", "velocity", "action")


def parse(argv=None) -> argparse.Namespace:
    import envs
    from ape_jax import tasks
    from ape_jax.pipeline.hints import image_size

    p = Parser(prog=PROG, description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help="a Brax task with image observations (default: hopper)")
    p.add_argument("--targets", default="pose,velocity", help=f"comma list of {', '.join(TARGETS)} (default: "
                   "pose,velocity), all predicted by one network")
    p.add_argument("--obs", default="image", choices=("image", "pos"),
                   help="what the network reads: image (default) or pos, the true pose (the sweep's state "
                        "observations; the reference an image encoder is measured against)")
    p.add_argument("--noise", type=float, default=0.0, metavar="F",
                   help="with --obs pos: a fixed Gaussian error on every observation, of variance F × the dimension's "
                        "training variance, drawn once per row: the pose as an encoder that reads it with "
                        "1 − R² = F would give it (default: 0)")
    p.add_argument("--image-size", default="32x32", help="the rendered frames' size, N (square), HxW or H,W "
                   "(default: 32x32, the CPU image presets')")
    p.add_argument("--encoder", default="small", help="the image encoder (default: small)")
    p.add_argument("--history", type=int, default=1, help="frames the network sees (default: 1)")
    p.add_argument("--iterations", type=int, default=5_000, help="Adam steps per run (default: 5,000)")
    p.add_argument("--points", default=None, metavar="N,...",
                   help="iterations at which to score (default: a fifth, half and all of --iterations)")
    p.add_argument("--seeds", type=int, default=2, help="runs per setting (default: 2)")
    p.add_argument("--train-episodes", default=None, metavar="N,...",
                   help="train on the first N training episodes, one setting per N (default: all of them)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", dest="sets",
                   help="any field of the sweep's records (e.g. recipe.encoder_norm=group, recipe.lr=6e-4)")
    p.add_argument("--out", type=pathlib.Path, required=True, help="the JSON file to write")
    p.add_argument("--data-dir", type=pathlib.Path, default=None, help="demonstration cache (default: the sweep's)")
    args = p.parse_args(argv)
    try:
        args.image_size = "x".join(map(str, image_size(args.image_size)))
    except ValueError as e:
        fail(p, f"--image-size {args.image_size!r}: {e}")
    posed = [t for t in tasks.sweepable() if "pos" in envs.obs_modes(t)]  # the tasks whose state is a pose
    if args.env not in posed:
        fail(p, f"--env {args.env!r}: one of the tasks with an expert and a pose ({', '.join(posed)})")
    args.targets = tuple(t.strip() for t in args.targets.split(",") if t.strip())
    bad = [t for t in args.targets if t not in TARGETS]
    if not args.targets or bad or len(set(args.targets)) != len(args.targets):
        fail(p, f"--targets {','.join(args.targets)!r}: a comma list of distinct {', '.join(TARGETS)}")
    if not 0.0 <= args.noise < float("inf") or (args.noise and args.obs != "pos"):
        fail(p, f"--noise {args.noise:g}: a number >= 0, with --obs pos only")
    for name in ("history", "iterations", "seeds"):
        if getattr(args, name) < 1:
            fail(p, f"--{name.replace('_', '-')} must be >= 1")
    args.points = _ints(p, "--points", args.points) if args.points else tuple(
        sorted({max(1, args.iterations // 5), max(1, args.iterations // 2), args.iterations}))
    if max(args.points) != args.iterations:
        fail(p, f"--points must end at --iterations ({args.iterations:,}), got {max(args.points):,}")
    args.train_episodes = _ints(p, "--train-episodes", args.train_episodes) if args.train_episodes else (None,)
    problem = unwritable_file(args.out)
    if problem:
        fail(p, f"--out {args.out}: {problem}")
    args.data_dir = data_directory(p, args.data_dir)
    return args


def _ints(p, flag: str, text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        fail(p, f"{flag} {text!r}: a comma list of integers")
    if not values or min(values) < 1 or list(values) != sorted(set(values)):
        fail(p, f"{flag} {text!r}: increasing integers >= 1")
    return values


def targets_of(demos, names) -> tuple[dict[str, slice], np.ndarray]:
    """`({name: columns}, [N, D] float32)`: the named targets of every row of `demos`, side by side."""
    import numpy as np

    columns = {"pose": np.asarray(demos.sim["qpos"])[:, 1:], "velocity": np.asarray(demos.sim["qvel"]),
               "action": np.asarray(demos.action)}
    out, where, at = [], {}, 0
    for name in names:
        out.append(columns[name].astype(np.float32))
        where[name] = slice(at, at + out[-1].shape[1])
        at += out[-1].shape[1]
    return where, np.concatenate(out, axis=1)


def run(args: argparse.Namespace, log=print) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from ape_jax.history import history_index
    from ape_jax.learner import Data, Hparams, make_train, policy_apply
    from ape_jax.pipeline.sweep import CPU_IMAGE_CHUNK, Hooks, SweepSpec, prepare
    from experiments._provenance import system
    from experiments._sweep_checks import demonstrations_writable

    started = system()  # the code that runs, taken at the start

    images = args.obs == "image"
    sets = [*([f"protocol.image_size={args.image_size}", f"recipe.encoder={args.encoder}"] if images else []),
            f"budget.iterations={args.iterations}", *args.sets]
    spec = SweepSpec.make(args.env, args.obs, protocol="brax", recipe="mlp", methods=["bc-oh"], preset="default",
                          sets=sets, data_dir=args.data_dir)
    demonstrations_writable(spec)   # before minutes of collecting into a --data-dir that cannot take them
    prepared = prepare(spec, Hooks(log=log))
    if not {"qpos", "qvel"} <= set(prepared.train.demos.sim):
        raise ValueError(f"{prepared.data_path}: the demonstrations hold no simulator state (sim/qpos, sim/qvel)")
    train_all, val = prepared.train.demos, prepared.val.demos
    where, y_train_all = targets_of(train_all, args.targets)
    _, y_val = targets_of(val, args.targets)
    mean, std = y_train_all.mean(0), y_train_all.std(0) + 1e-6
    raw_var = {name: y_train_all[:, cols].var(0) for name, cols in where.items()}
    cfg = spec.settings.learner_config(prepared.env.observation_shape, y_train_all.shape[1], args.history, "l2",
                                       unroll=prepared.sequential(spec.recipe.encoder))
    learner = make_train(cfg)
    chunk = CPU_IMAGE_CHUNK if cfg.unroll else 100
    hp = Hparams.make("uniform", lr=spec.recipe.lr)

    def data_of(demos, y, seed):
        obs = prepared.normalizer(demos.obs)
        if args.noise:  # standardised observations: the training variance is 1 per dimension
            obs = obs + np.sqrt(args.noise) * np.random.default_rng(seed).standard_normal(obs.shape, np.float32)
        return Data(obs=jnp.asarray(obs), action=jnp.asarray((y - mean) / std), t=jnp.asarray(demos.t),
                    ape=jnp.ones(len(y), jnp.float32))

    predict_jit = jax.jit(lambda params, x: policy_apply(cfg.model(), params, x)[0])

    def predict(params, data):  # standardised predictions of every row, 256 frames at a time
        out = []
        for start in range(0, data.size, 256):
            idx = jnp.arange(start, min(start + 256, data.size))
            x = learner.policy_input(data.obs[history_index(data.t, idx, cfg.history)])
            out.append(np.asarray(predict_jit(params, x)))
        return np.concatenate(out)

    val_data = data_of(val, y_val, 1)
    episodes = train_all.episode_ids
    record = {"command": ["python", "-m", "experiments.pose_probe", *args.argv], "env": args.env, "obs": args.obs,
              "noise": args.noise,
              "image_size": list(prepared.env.observation_shape[:2]) if images else None,
              "encoder": args.encoder if images else spec.recipe.network,
              "history": args.history, "targets": list(args.targets), "points": list(args.points),
              "recipe": spec.settings.to_json()["recipe"], "data": prepared.data_path,
              "train_episodes_available": int(len(episodes)), "val_episodes": int(val.num_episodes),
              "val_rows": len(val), "system": started, "runs": []}
    steps = {}  # one compiled call per chunk length (a shorter one to land on each point)

    def step(state, data, n):
        if n not in steps:  # the data is an argument, not a constant folded into the program
            steps[n] = jax.jit(lambda s, d: learner.run(s, hp, d, n))
        return steps[n](state, data)

    too_many = [n for n in args.train_episodes if n is not None and n > len(episodes)]
    if too_many:
        raise ValueError(f"--train-episodes {too_many[0]}: the training split has {len(episodes)} episodes")
    for n_episodes in args.train_episodes:
        # a subset keeps the whole training split's standardisation and variances: its scores compare with the rest
        chosen = train_all if n_episodes is None else train_all.select_episodes(episodes[:n_episodes])
        _, y = targets_of(chosen, args.targets)
        train = data_of(chosen, y, 0)
        for seed in range(args.seeds):
            state, done, at, t0 = jax.jit(learner.init)(jax.random.PRNGKey(seed), hp, train), 0, [], time.perf_counter()
            while done < args.iterations:
                n = min(chunk, min(p for p in args.points if p > done) - done)
                state, _ = step(state, train, n)
                done += n
                for point in (p for p in args.points if p == done):
                    params = learner.policy_params(state)
                    at.append({"iteration": point, **{
                        split: scores(predict(params, d) * std + mean, y_true, where, raw_var)
                        for split, d, y_true in (("train", train, y), ("val", val_data, y_val))}})
                    log(f"episodes {chosen.num_episodes}, seed {seed}, {point:,} iterations: " + "; ".join(
                        f"{name} 1-R² train {at[-1]['train'][name]['one_minus_r2']:.3f} val "
                        f"{at[-1]['val'][name]['one_minus_r2']:.3f}" for name in args.targets)
                        + f" ({time.perf_counter() - t0:.0f} s)")
            record["runs"].append({"train_episodes": int(chosen.num_episodes), "train_rows": len(chosen),
                                   "seed": seed, "seconds": time.perf_counter() - t0, "at": at})
    return record


def scores(pred, y_true, where, raw_var) -> dict:
    """Per target group of predictions `pred` (on the targets' scale): `1 − R²` (MSE ÷ the training rows'
    variance, averaged over its dimensions), and for `action` the BC loss (squared error summed over
    dimensions, mean over rows)."""
    import numpy as np

    out = {}
    for name, cols in where.items():
        e = pred[:, cols] - y_true[:, cols]
        mse = (e ** 2).mean(0)
        out[name] = {"one_minus_r2": float(np.mean(mse / raw_var[name])),
                     "per_dim": [float(v) for v in mse / raw_var[name]]}
        if name == "action":
            out[name]["bc_loss"] = float((e ** 2).sum(1).mean())
    return out


def table(record: dict) -> str:
    import numpy as np

    seen = (f"{record['image_size'][0]}×{record['image_size'][1]} frames, encoder {record['encoder']}"
            if record["image_size"] else f"the true pose ({record['obs']}"
            + (f", error of {record['noise']:g} × its variance" if record.get("noise") else "")
            + f"), network {record['encoder']}")
    lines = [f"{record['env']}, {seen}, history {record['history']}: 1 − R² (median over seeds; 0 = read exactly, "
             f"1 = not at all)", "",
             "| train episodes | iterations | " + " | ".join(f"{t} train | {t} val" for t in record["targets"]) + " |",
             "|---:|---:|" + "---:|---:|" * len(record["targets"])]
    for n in sorted({r["train_episodes"] for r in record["runs"]}):
        runs = [r for r in record["runs"] if r["train_episodes"] == n]
        for point in record["points"]:
            cells = []
            for t in record["targets"]:
                for split in ("train", "val"):
                    v = [a[split][t]["one_minus_r2"] for r in runs for a in r["at"] if a["iteration"] == point]
                    cells.append(f"{np.median(v):.3f}")
            lines.append(f"| {n} | {point:,} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = parse(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    from ape_jax.pipeline.data import DataError
    from envs.experts import ExpertError

    try:
        record = run(args)
    except (DataError, ExpertError, ValueError) as e:
        fail(None, str(e))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(args.out.suffix + ".tmp")
    tmp.write_text(json.dumps(record, indent=1) + "\n")
    tmp.replace(args.out)
    print(table(record))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
