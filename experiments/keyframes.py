"""Draws one expert episode's keyframes as a picture: `python -m experiments.keyframes --env hopper`.

For one episode of the shipped expert's cached demonstrations (those the sweep
uses under `--protocol`, by default the task's: `mujoco-state` (frame skip 1) for
MuJoCo, where the picture is `figures/keyframes-ENV.png`, or e.g. `brax`,
`figures/keyframes-ENV-brax.png`; `pos` observations for MuJoCo, `full` for
ToyCar; seed 0): APE along time with its keyframes, the expert's actions (a
`--zoom` close-up for a long episode), and frames rendered from the recorded
simulator states at the `--frames` highest-APE keyframes and `--ordinary`
low-APE steps (`ape_jax.pipeline.keyframes.select`, drawn by `experiments.report.figures.keyframes`).

APE is fitted on **all** the demonstrations (the sweep fits on its training
split only; see `experiments.weights`); the keyframes are the top `--thr`
(default 10%, the paper's THR) of APE over the whole dataset, the samples
`ape_jax.weighting.step` upweights, so one episode can hold more or fewer.

Bad input (unknown env, an episode out of range, non-positive counts, an
`--out` that is not a writable `.png`) is refused with one line on stderr and
exit status 2 before anything is compiled.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

from ape_jax import tasks
from experiments._cli import Parser, data_directory, fail, unwritable, unwritable_file


def demo_obs(env_name: str) -> str:
    """The state observations of `env_name`'s demonstrations: `pos` where it has them (MuJoCo), else `full`."""
    import envs

    return "pos" if "pos" in envs.obs_modes(env_name) else "full"


def parse(argv=None) -> argparse.Namespace:
    from ape_jax.pipeline import collect, data
    from ape_jax.pipeline.hints import image_size

    p = Parser(prog="python -m experiments.keyframes", description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help=f"one of {', '.join(tasks.sweepable())} (default: hopper)")
    p.add_argument("--protocol", default=None,
                   help=f"{', '.join(tasks.PROTOCOLS)} (default: the task's, as the sweep's: mujoco-state for MuJoCo)")
    p.add_argument("--episode", type=int, default=0, help="which demonstration episode to draw (default: 0)")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="the PNG to write (default: figures/keyframes-ENV.png)")
    p.add_argument("--frames", type=int, default=4, help="keyframes to render (default: 4)")
    p.add_argument("--ordinary", type=int, default=1,
                   help="ordinary (low-APE) frames rendered for contrast (default: 1)")
    p.add_argument("--min-gap", type=int, default=None,
                   help="fewest steps between two rendered frames (default: episode length / (2 x frames shown))")
    p.add_argument("--zoom", type=int, default=150,
                   help="steps around the highest-APE keyframe shown close up (default: 150; 0, or an episode "
                        "shorter than twice this: the actions along the whole episode instead)")
    p.add_argument("--image-size", default="96", help="the rendered frames' size in pixels, N (square), HxW or H,W "
                   "(default: 96)")
    p.add_argument("--ape-steps", type=int, default=5000, help="Adam steps fitting the APE model (default: 5000)")
    p.add_argument("--thr", type=float, default=0.1, help="fraction of the dataset that are keyframes (default: 0.1)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the APE fit (default: 0)")
    p.add_argument("--data-dir", type=pathlib.Path, default=None,
                   help=f"demonstrations cache (default: {data.cache_dir()})")
    args = p.parse_args(argv)
    try:
        args.image_size = image_size(args.image_size)
    except ValueError as e:
        fail(p, f"--image-size {args.image_size!r}: {e}")
    if args.env not in tasks.sweepable():
        fail(p, f"unknown env {args.env!r}; valid: {', '.join(tasks.sweepable())}")
    try:
        args.setup = collect.protocol_setup(args.env, demo_obs(args.env), args.protocol)
    except ValueError as e:
        fail(p, str(e))
    episodes = args.setup.episodes
    if not 0 <= args.episode < episodes:
        fail(p, f"--episode must be in [0, {episodes - 1}] ({args.env} has {episodes} demonstration episodes), "
                f"got {args.episode}")
    for flag, value, least in (("--frames", args.frames, 1),
                               ("--ape-steps", args.ape_steps, 1), ("--ordinary", args.ordinary, 0),
                               ("--zoom", args.zoom, 0),
                               ("--min-gap", 1 if args.min_gap is None else args.min_gap, 1)):
        if value < least:
            fail(p, f"{flag} must be >= {least}, got {value}")
    if args.frames + args.ordinary > 12:
        fail(p, f"--frames + --ordinary must be <= 12 (one row of pictures), got {args.frames + args.ordinary}")
    if max(args.image_size) > 1024:
        fail(p, f"--image-size must be at most 1024 pixels a side, got {'x'.join(map(str, args.image_size))}")
    if not 0.0 < args.thr < 1.0:
        fail(p, f"--thr must be in (0, 1), got {args.thr}")
    default = tasks.get(args.env).protocol(None, demo_obs(args.env)).name
    suffix = "" if args.setup.name == default else f"-{args.setup.name}"
    args.out = args.out or pathlib.Path("figures") / f"keyframes-{args.env}{suffix}.png"
    if args.out.suffix.lower() != ".png":
        fail(p, f"--out must name a .png file, got {args.out}")
    why = unwritable_file(args.out)
    if why:
        fail(p, f"--out {args.out}: cannot write there: {why}")
    args.data_dir = data_directory(p, args.data_dir)
    return args


def main(argv=None) -> int:
    args = parse(argv)
    import jax
    import jax.numpy as jnp

    import envs
    from ape_jax import ape as ape_lib
    from ape_jax.pipeline import collect, data, keyframes
    from experiments.report import figures
    from envs.experts import ExpertError
    from tqdm import tqdm

    started = time.perf_counter()
    try:
        cfg = collect.data_key(args.env, demo_obs(args.env), args.setup.episodes, seed=0, **args.setup.env_overrides)
    except ExpertError as e:
        return fail(None, str(e))
    if not data.cache_path(args.data_dir, cfg).exists():
        why = unwritable(args.data_dir)
        if why:
            return fail(None, f"--data-dir {args.data_dir}: the demonstrations are not cached and cannot be "
                        f"collected there: {why}")
    try:
        demos, _, path, cached = collect.collect_cached(cfg, args.data_dir)
    except data.DataError as e:
        return fail(None, f"{e}; run `python -m experiments.collect --env {args.env} --obs {cfg['obs']} --force` "
                    "to collect it anew")
    except OSError as e:
        return fail(None, f"--data-dir {args.data_dir}: cannot write the demonstrations ({e.strerror or e})")
    if not demos.sim:
        return fail(None, f"{path}: the dataset records no simulator states, so its frames cannot be rendered")
    if args.episode not in demos.episode_ids:
        return fail(None, f"--episode {args.episode}: not in {path} (episodes {demos.episode_ids.min()}.."
                    f"{demos.episode_ids.max()})")

    with tqdm(total=args.ape_steps, desc="fit APE", unit="step", delay=1.0, dynamic_ncols=True) as bar:
        ape_raw = ape_lib.fit_all(demos.action, demos.t, args.ape_steps, args.seed, bar)
    try:
        ape_all, _, scale = ape_lib.normalize(ape_raw, ape_raw[:0], "mean")
    except ValueError as e:
        return fail(None, f"{path}: {e}")
    ape_all = np.asarray(ape_all)
    is_key, threshold = keyframes.keyframe_mask(ape_all, args.thr)
    rows = np.flatnonzero(np.asarray(demos.episode) == args.episode)
    ape_ep, key_ep, actions = ape_all[rows], is_key[rows], np.asarray(demos.action)[rows]
    pick = keyframes.select(ape_ep, key_ep, args.frames, args.ordinary, args.min_gap, args.zoom, skip_start=ape_lib.K)

    env = envs.make(args.env, obs="image", image_size=args.image_size, **args.setup.env_overrides)
    sims = jax.tree.map(lambda x: jnp.asarray(np.asarray(x)[rows[pick.steps]]), demos.sim)
    frames = (np.asarray(jax.jit(jax.vmap(env.observe_sim))(sims)) if len(pick.steps)
              else np.zeros((0, 1, 1, 3), np.uint8))

    n_key = int(key_ep.sum())
    title = (f"{args.env} expert ({args.setup.name} protocol, frame skip {args.setup.settings['frame_skip'] or '-'}), "
             f"episode {args.episode}: {n_key} of {len(rows)} steps ({n_key / len(rows):.0%}) are keyframes")
    # how much of the actions' variance ψ explains from the previous actions: near 1 where consecutive actions are
    # nearly equal (a high frame rate), and the keyframes are then the few steps it cannot extrapolate
    explained = 1.0 - float(np.mean(ape_raw)) / float(np.sum(np.var(np.asarray(demos.action), axis=0)))
    note = (f"keyframes = top {args.thr:.0%} APE over all {len(demos):,} steps of the {demos.num_episodes} "
            f"demonstrations (APE model fitted on all of them, {args.ape_steps} Adam steps; "
            f"APE ÷ its mean {scale:.3g}; ψ explains {explained:.1%} of the actions' variance)")
    fig = figures.keyframes(ape_ep, actions, threshold, frames, pick.steps, keyframe=key_ep, title=title, note=note,
                            action_names=keyframes.action_names(env), frame_is_key=pick.is_key, window=pick.window)
    try:
        size = figures.save_png(fig, args.out)
    except OSError as e:
        return fail(None, f"--out {args.out}: cannot write ({e.strerror or e})")
    shown = ", ".join(f"t={t}{'*' if k else ''}" for t, k in zip(pick.steps, pick.is_key))
    print(f"{args.out} ({size / 1024:.0f} KB)\nψ fit: mean APE {scale:.4g}, {explained:.1%} of the actions' variance "
          f"(Σ_d Var(a_d)) explained by the previous {ape_lib.K} actions; top-{args.thr:.0%} APE share of the total "
          f"APE: {float(np.sort(ape_all)[::-1][:int(args.thr * len(ape_all))].sum() / ape_all.sum()):.1%}")
    print(f"{args.env} episode {args.episode}: {n_key}/{len(rows)} keyframes "
          f"(threshold {threshold:.3g} x mean APE); frames at {shown} (* keyframe); "
          f"{'cached' if cached else 'collected'} demonstrations {path.name}; {time.perf_counter() - started:.0f} s")
    if n_key < args.frames:
        ids, counts = np.unique(np.asarray(demos.episode)[is_key], return_counts=True)
        richest = ", ".join(f"{e} ({c})" for e, c in sorted(zip(ids, counts), key=lambda ec: -ec[1])[:3])
        print(f"note: episode {args.episode} holds {n_key} keyframes, fewer than --frames {args.frames}; "
              f"the episodes with the most: {richest or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
