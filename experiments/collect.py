"""Collects expert demonstrations: `python -m experiments.collect --env hopper --obs pos`.

Under `--protocol` (default: the task's, as the sweep: `mujoco-state` for state
observations, `brax` for images and ToyCar), with its frame skip, episode
length, reward scale and number of expert steps, so the dataset is the one a
sweep of the same protocol collects (and accepts with `--dataset`).

Rolls the shipped expert out under jit and writes the dataset (`.npz` plus
`.json` metadata, see `ape_jax.pipeline.data`) into the cache directory, named by a hash
of the settings; a second run with the same settings loads it instead. The
sweep uses the same cache. `--set protocol.FIELD=VALUE` changes a field of the
protocol as the sweep's `--set` does: `protocol.expert=NAME` collects from an
expert variant (shipped, or imported with `experiments.import_expert`),
`protocol.labels=raw` stores the expert's output as it gives it (the executed
action is clipped to the action bounds either way). The metadata records the
labels' mode, the share of the expert's raw label entries outside the action
range, and the expert's reference returns under the protocol.

`--format minari` also exports the dataset as a Minari dataset (see
`ape_jax.pipeline.minari_io`) with id `<npz name>-v0` under the Minari datasets root
`--out DIR` (default: `minari/` in the cache directory), for tools that read
Minari: `MINARI_DATASETS_PATH=DIR` then `minari.load_dataset(id)`.

Bad input is refused with one line on stderr and exit status 2 before anything
is compiled: unknown env or observation mode, out-of-range counts or noise,
a `--data-dir`, `--out` or `--preview` that cannot be written, or a cached
dataset that is corrupt (it is left in place; `--force` collects it anew).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import pathlib
import sys

from experiments._cli import (EPISODES_LIMIT, Parser, add_compile_cache_flag, data_directory, fail, interruptible,
                             raise_if_interrupted, unwritable, unwritable_file, use_compile_cache)


def parse(argv=None) -> argparse.Namespace:
    import envs
    from ape_jax import tasks
    from ape_jax.pipeline import collect, data
    from ape_jax.pipeline.hints import image_size
    from ape_jax.pipeline.presets import BUDGET_MAX, current_protocol, parse_set

    p = Parser(prog="python -m experiments.collect", description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help=f"{', '.join(tasks.sweepable())}, or any Brax env with an expert "
                                                   "(default: hopper)")
    p.add_argument("--obs", default=None, help="full, pos or image (default: the task's, e.g. pos for MuJoCo)")
    p.add_argument("--protocol", default=None,
                   help=f"{', '.join(tasks.PROTOCOLS)} (default: the task's, as the sweep's: mujoco-state for state "
                        "observations, brax for images)")
    p.add_argument("--set", action="append", default=[], metavar="protocol.FIELD=VALUE",
                   help="change a field of the protocol, as the sweep's --set (e.g. protocol.expert=cs294, "
                        "protocol.labels=raw)")
    p.add_argument("--episodes", type=int, default=None,
                   help="episodes to collect (default: the protocol's: mujoco-state's 50,000 expert steps, 25 "
                        "episodes of 2,000 steps for Hopper; under brax the task's: 25 for MuJoCo, 10 for the driving "
                        "sandbox)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--noise-frac", type=float, default=None,
                   help="share of the steps whose executed action is perturbed (the label stays the expert's; "
                        "default: the protocol's, 0.1 for nocrash, else 0)")
    p.add_argument("--noise-std", type=float, default=None,
                   help="std of the Gaussian action noise (default: the protocol's)")
    p.add_argument("--noise-steps", type=int, default=None,
                   help="steps per burst of noise, 1: each step on its own (default: the protocol's, 10 for nocrash)")
    p.add_argument("--image-size", default=None,
                   help="with --obs image: the frames' size, N (square), HxW or H,W (default: the env's)")
    p.add_argument("--batch", type=int, default=32, help="episodes per jitted call")
    p.add_argument("--data-dir", type=pathlib.Path, default=None, help=f"cache directory (default: {data.cache_dir()})")
    p.add_argument("--force", action="store_true", help="collect (and export) again even if the dataset is cached")
    p.add_argument("--format", choices=("npz", "minari"), default="npz",
                   help="npz (default): the cached .npz + .json only; minari: also export a Minari dataset")
    p.add_argument("--out", type=pathlib.Path, default=None, metavar="DIR",
                   help="with --format minari: the Minari datasets root to export into (default: DATA_DIR/minari)")
    p.add_argument("--preview", type=pathlib.Path, default=None, metavar="FILE.gif",
                   help="also write the first episode's first 300 steps as a GIF, rendered from the recorded "
                        "simulator states")
    p.add_argument("--yes", action="store_true",
                   help=f"collect more than {EPISODES_LIMIT:,} episodes (the sweep's limit on episodes), which is "
                        "refused without it")
    add_compile_cache_flag(p)
    args = p.parse_args(argv)
    use_compile_cache(args)
    if args.env not in envs.names():
        fail(p, f"unknown env {args.env!r}; valid: {', '.join(envs.names())}")
    modes = envs.obs_modes(args.env)
    default = tasks.get(args.env).default_obs
    args.obs = args.obs or (default if default in modes else envs.default_obs(args.env))
    if args.obs not in modes:
        fail(p, f"--obs {args.obs!r} is not supported by {args.env}; valid: {', '.join(modes)}")
    try:
        proto = tasks.get(args.env).protocol(current_protocol(args.protocol), args.obs)
        changes = {}
        for item in args.set:
            section, field, value = parse_set(item)
            if section != "protocol":
                raise ValueError(f"--set {item!r}: collection takes protocol fields only")
            changes[field] = value
        args.protocol_record = dataclasses.replace(proto, **changes)
        args.setup = collect.protocol_setup(args.env, args.obs, args.protocol_record)
        if args.protocol_record.frames != "rollout":
            raise ValueError("protocol.frames=states renders a state dataset's rows when a sweep reads them: collect "
                             "that state dataset with --obs pos (and the protocol's other settings)")
    except ValueError as e:
        fail(p, str(e))
    if args.episodes is None:
        args.episodes = args.setup.episodes
    for flag, value in (("--episodes", args.episodes), ("--batch", args.batch)):
        if value < 1:
            fail(p, f"{flag} must be >= 1, got {value}")
    if args.episodes > BUDGET_MAX:   # episode ids are 32-bit integers
        fail(p, f"--episodes must be at most {BUDGET_MAX:,} (episodes are numbered in 32-bit integers), got "
                f"{args.episodes:,}")
    if args.episodes > EPISODES_LIMIT and not args.yes:
        fail(p, f"--episodes {args.episodes:,} is over the limit of {EPISODES_LIMIT:,} episodes (every step is kept "
                "in memory and on disk); pass --yes to collect them anyway, or ask for fewer")
    for name in ("noise_frac", "noise_std", "noise_steps"):
        if getattr(args, name) is None:
            setattr(args, name, args.setup.settings.get(name, 1 if name == "noise_steps" else 0.0))
    if args.noise_steps < 1:
        fail(p, f"--noise-steps must be >= 1, got {args.noise_steps}")
    if not 0.0 <= args.noise_frac <= 1.0:
        fail(p, f"--noise-frac must be in [0, 1], got {args.noise_frac}")
    if not 0.0 <= args.noise_std < math.inf:
        fail(p, f"--noise-std must be a finite number >= 0, got {args.noise_std}")
    args.overrides = dict(args.setup.env_overrides)
    if args.image_size is not None:
        if args.obs != "image":
            fail(p, "--image-size applies to --obs image only")
        try:
            args.overrides["image_size"] = image_size(args.image_size)
        except ValueError as e:
            fail(p, f"--image-size {args.image_size!r}: {e}")
    try:   # the task's own checks (e.g. ToyTown's smallest image), before anything is collected or written
        envs.make(args.env, obs=args.obs, **args.overrides)
    except ValueError as e:
        fail(p, f"--env {args.env}: {e}")
    if args.preview is not None:
        if args.preview.suffix != ".gif":
            fail(p, f"--preview must name a .gif file, got {args.preview}")
        why = unwritable_file(args.preview)
        if why:
            fail(p, f"--preview {args.preview}: cannot write there: {why}")
    args.data_dir = data_directory(p, args.data_dir)
    if args.out is not None and args.format != "minari":
        fail(p, "--out applies to --format minari only")
    args.out = args.out or args.data_dir / "minari"
    if args.format == "minari":
        if args.out.exists() and not args.out.is_dir():
            fail(p, f"--out {args.out} is a file; it must be a directory (the Minari datasets root)")
        why = unwritable(args.out)
        if why:
            fail(p, f"--out {args.out}: cannot write there: {why}")
    return args


def action_summary(demos) -> str:
    """Per action dimension: mean, std, and how many steps (in how many episodes) lie beyond 2 std of the mean:
    the rare actions, such as ToyCar's braking for a red light, that a cloned policy may never learn."""
    import numpy as np

    actions, episode = np.asarray(demos.action), np.asarray(demos.episode)
    lines = []
    for d in range(actions.shape[1]):
        a = actions[:, d]
        rare = np.abs(a - a.mean()) > 2 * a.std()
        lines.append(f"action {d}: mean {a.mean():.3f}, std {a.std():.3f}; beyond 2 std in {int(rare.sum()):,} of "
                     f"{len(a):,} steps ({rare.mean():.1%}), in {len(np.unique(episode[rare]))} of "
                     f"{demos.num_episodes} episodes")
    return "\n".join(lines)


@interruptible("a dataset is cached only once collected whole")
def main(argv=None) -> int:
    args = parse(argv)
    from tqdm import tqdm

    from ape_jax.pipeline import collect, data
    from envs.experts import ExpertError

    try:
        cfg = collect.data_key(args.env, args.obs, args.episodes, args.setup.expert, seed=args.seed,
                               noise_frac=args.noise_frac, noise_std=args.noise_std, batch=args.batch,
                               labels=args.setup.labels,
                               noise_steps=args.noise_steps if args.noise_frac > 0 else 1, **args.overrides)
        references, why = _references(args)
    except ExpertError as e:
        return fail(None, str(e))
    path = data.cache_path(args.data_dir, cfg)
    if args.force or not path.exists():  # the dataset will be written: refuse now rather than after collecting
        why = unwritable(args.data_dir)
        if why:
            return fail(None, f"--data-dir {args.data_dir}: cannot write the dataset there: {why}")
    try:
        with tqdm(total=args.episodes, unit="episode", desc=f"collect {args.env}/{args.obs}", delay=0.5) as bar:
            demos, meta, path, cached = collect.collect_cached(
                cfg, args.data_dir, force=args.force, progress=lambda n: _progress(bar, n),
                references=references)
    except data.DataError as e:
        return fail(None, f"{e}; the cached dataset is left as it is: run again with --force to collect it anew")
    except OSError as e:
        return fail(None, f"--data-dir {args.data_dir}: cannot write the dataset ({e.strerror or e})")
    sizes = args.setup.settings
    try:  # the split the sweep makes (`data.split_parts`): the protocol's kind (rows or episodes) and sizes
        train, val = data.split_parts(demos, sizes["split"], sizes["train_transitions"], sizes["val_transitions"],
                                      seed=0)
        how = (f"the {args.setup.name} protocol's split by "
               f"{'rows (a fixed permutation of all rows)' if sizes['split'] == 'rows' else 'whole episodes'}")
    except ValueError as e:
        train, val = demos.split()
        how = f"the 20% split by whole episodes (the protocol's cannot be made: {e})"
    print(f"{'loaded cached' if cached else 'collected'} {len(demos):,} transitions in {demos.num_episodes} "
          f"episodes under the {args.setup.name} protocol (frame skip {sizes['frame_skip'] or '-'}, "
          f"{sizes['episode_length']:,}-step episodes); {len(train):,} train / {len(val):,} validation after "
          f"{how}; "
          f"expert return {meta['episode_return_mean']:.1f} ± {meta['episode_return_std']:.1f}, "
          f"mean episode length {meta['episode_length_mean']:.0f}")
    labels = meta.get("labels")
    if labels:
        print(f"labels: {labels['mode']}; {labels['raw_outside_share']:.1%} of the expert's raw label entries lie "
              f"outside the action range (from {labels['raw_min']:.3g} to {labels['raw_max']:.3g})")
    if not cached and references is None and why:
        print(f"no reference returns recorded: {why}")
    print(action_summary(demos))
    print(f"dataset: {path}\nmetadata: {path.with_suffix('.json')}")
    if args.format == "minari":
        export_minari(args, demos, meta, path)
    if args.preview is not None:
        write_preview(args, demos)
    return 0


def _progress(bar, n: int) -> None:
    raise_if_interrupted()   # between batches: a Ctrl-C whose exception was ignored stops collecting here
    bar.update(n - bar.n)


def _references(args) -> tuple[dict | None, str | None]:
    """The protocol's reference returns of the expert collecting (`collect.reference_returns`), and why there are
    none (a rule-based expert, or none measured under the protocol)."""
    from ape_jax.pipeline import collect
    from envs.experts import ExpertError

    try:
        ref = collect.reference_returns(args.env, args.protocol_record)
    except ExpertError as e:
        return None, str(e)
    return ref, "its expert is rule-based (no returns to normalise by)" if ref is None else None


def export_minari(args, demos, meta, path) -> None:
    import envs
    from ape_jax.pipeline import minari_io

    dataset_id = f"{path.stem}-v0"
    target = args.out / dataset_id
    if target.exists() and not args.force:
        print(f"minari dataset: {target} (exported before)")
        return
    env = envs.make(args.env, obs=args.obs, **args.overrides)
    # the reference scores of minari.get_normalized_score: the protocol's random policy and expert
    ref, why = _references(args)
    refs = {} if ref is None else {"ref_min_score": ref["random_return_mean"], "ref_max_score": ref["return_mean"]}
    try:
        target = minari_io.to_minari(demos, meta, dataset_id, args.out, action_bounds=env.action_bounds,
                                     overwrite=True, **refs)
    except OSError as e:
        fail(None, f"--out {args.out}: cannot write the Minari dataset ({e.strerror or e})")
    print(f"minari dataset: {target} (id {dataset_id!r}; MINARI_DATASETS_PATH={args.out} to load it by id)")
    print(f"reference scores: random {refs['ref_min_score']:,.1f}, expert {refs['ref_max_score']:,.1f} "
          "(minari.get_normalized_score works on it)" if refs else f"no reference scores: {why}")


def write_preview(args, demos) -> None:
    import numpy as np

    import envs
    from envs import video

    first = demos.take(np.flatnonzero(demos.episode == demos.episode_ids[0])[:300])
    env = envs.make(args.env, obs="image", **args.overrides)
    frames = video.render_sim_states(env, first.sim)
    video.save_frames(frames, str(args.preview), fps=min(50, round(1 / env.dt)), scale=max(1, 128 // frames.shape[1]))
    print(f"preview: {args.preview} ({len(frames)} frames)")


if __name__ == "__main__":
    sys.exit(main())
