"""Draws one expert episode's keyframes as a picture: `python -m experiments.keyframes --env hopper`.

The picture (PNG) shows, for one episode of the shipped expert's cached
demonstrations (the ones the sweep uses: `pos` observations for MuJoCo,
`full` for ToyCar, the default number of episodes, seed 0):

- top: the action prediction error along time, divided by its mean over the
  dataset, with the keyframes marked in red and the keyframe threshold dashed;
- middle: the expert's actions, keyframes shaded, so one sees that keyframes
  are where the actions change. A long episode (MuJoCo's 1000 steps) gets a
  close-up instead: the APE and the actions over `--zoom` steps around its
  highest-APE keyframe, marked grey on the top row;
- bottom: frames rendered from the recorded simulator states (not
  re-simulated) at the `--frames` highest-APE keyframes, spread out in time,
  and at one ordinary (low-APE) step for contrast, each labelled with its
  step and APE.

APE is fitted on **all** the demonstrations (the sweep fits on its training
split only, so its numbers differ slightly; see `experiments.weights`), and
the keyframes are the top `--thr` (default 10%, the paper's THR) of APE over
the whole dataset, the samples `ape_jax.weighting.step` upweights. The same
threshold then marks the keyframes of the chosen episode, so an episode can
hold more or fewer than 10% of them.

Bad input (unknown env, an episode out of range, non-positive counts, an
`--out` that is not a writable `.png`) is refused with one line on stderr and
exit status 2 before anything is compiled.

`draw` builds the figure from plain arrays and `pick_frames` chooses the
steps to show; both are pure and need no simulator.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

from experiments._cli import Parser, fail, unwritable, unwritable_file

ENVS = ("hopper", "halfcheetah", "walker2d", "toycar")
KEY_COLOR, ORDINARY_COLOR = "#d62728", "#1f77b4"


def demo_obs(env_name: str) -> str:
    """The observation mode of the demonstrations the sweep uses by default for `env_name`."""
    return "full" if env_name == "toycar" else "pos"


def parse(argv=None) -> argparse.Namespace:
    from ape_jax import collect, data

    p = Parser(prog="python -m experiments.keyframes", description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help=f"one of {', '.join(ENVS)} (default: hopper)")
    p.add_argument("--episode", type=int, default=0, help="which demonstration episode to draw (default: 0)")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="the PNG to write (default: figures/keyframes-ENV.png)")
    p.add_argument("--frames", type=int, default=4, help="keyframes to render (default: 4)")
    p.add_argument("--ordinary", type=int, default=1, help="ordinary (low-APE) frames rendered for contrast (default: 1)")
    p.add_argument("--min-gap", type=int, default=None,
                   help="fewest steps between two rendered frames (default: episode length / (2 x frames shown))")
    p.add_argument("--zoom", type=int, default=150,
                   help="steps around the highest-APE keyframe shown close up (default: 150; 0, or an episode "
                        "shorter than twice this: the actions along the whole episode instead)")
    p.add_argument("--image-size", type=int, default=96, help="side of the rendered frames in pixels (default: 96)")
    p.add_argument("--ape-steps", type=int, default=5000, help="Adam steps fitting the APE model (default: 5000)")
    p.add_argument("--thr", type=float, default=0.1, help="fraction of the dataset that are keyframes (default: 0.1)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the APE fit (default: 0)")
    p.add_argument("--data-dir", type=pathlib.Path, default=None,
                   help=f"demonstrations cache (default: {data.cache_dir()})")
    args = p.parse_args(argv)
    if args.env not in ENVS:
        fail(p, f"unknown env {args.env!r}; valid: {', '.join(ENVS)}")
    episodes = collect.default_episodes(args.env)
    if not 0 <= args.episode < episodes:
        fail(p, f"--episode must be in [0, {episodes - 1}] ({args.env} has {episodes} demonstration episodes), "
                f"got {args.episode}")
    for flag, value, least in (("--frames", args.frames, 1), ("--image-size", args.image_size, 1),
                               ("--ape-steps", args.ape_steps, 1), ("--ordinary", args.ordinary, 0),
                               ("--zoom", args.zoom, 0),
                               ("--min-gap", 1 if args.min_gap is None else args.min_gap, 1)):
        if value < least:
            fail(p, f"{flag} must be >= {least}, got {value}")
    if args.frames + args.ordinary > 12:
        fail(p, f"--frames + --ordinary must be <= 12 (one row of pictures), got {args.frames + args.ordinary}")
    if args.image_size > 1024:
        fail(p, f"--image-size must be <= 1024, got {args.image_size}")
    if not 0.0 < args.thr < 1.0:
        fail(p, f"--thr must be in (0, 1), got {args.thr}")
    args.out = args.out or pathlib.Path("figures") / f"keyframes-{args.env}.png"
    if args.out.suffix.lower() != ".png":
        fail(p, f"--out must name a .png file, got {args.out}")
    why = unwritable_file(args.out)
    if why:
        fail(p, f"--out {args.out}: cannot write there: {why}")
    args.data_dir = args.data_dir or data.cache_dir()
    if args.data_dir.exists() and not args.data_dir.is_dir():
        fail(p, f"--data-dir {args.data_dir} is a file; it must be a directory")
    return args


# -- pure parts ---------------------------------------------------------------------------------

def keyframe_mask(ape: np.ndarray, thr: float) -> tuple[np.ndarray, float]:
    """The top `thr` of `ape` as `ape_jax.weighting.step` picks them (⌊thr·N⌋ largest, ties by index).

    Args:
      ape: `[N]` APE over the whole dataset.
      thr: fraction in (0, 1).

    Returns:
      (mask, threshold): `[N] bool`, and the smallest APE among the keyframes
      (+inf when ⌊thr·N⌋ = 0).
    """
    from ape_jax import weighting

    ape = np.asarray(ape, np.float32)
    mask = np.asarray(weighting.step(ape, thr, 2.0)) > 1.0
    return mask, float(ape[mask].min()) if mask.any() else float("inf")


def pick_frames(ape: np.ndarray, keyframe: np.ndarray, count: int, min_gap: int, ordinary: int = 1,
                skip_start: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """The steps of one episode worth rendering: its highest-APE keyframes, spread out, and ordinary steps.

    Keyframes are taken greedily by decreasing APE, each at least `min_gap`
    steps from those already taken; then up to `ordinary` non-keyframe steps of
    lowest APE, equally spread, skipping the first `skip_start` steps (where
    APE is near zero only because the missing past actions are padded).

    Args:
      ape: `[T]` APE of the episode's steps.
      keyframe: `[T] bool`, which of them are keyframes.
      count: keyframes wanted (fewer come back when not enough are far enough apart).
      min_gap: fewest steps between two picked steps, >= 1.
      ordinary: ordinary steps wanted.
      skip_start: ordinary steps are not taken before this step.

    Returns:
      (steps, is_key): `[k] int` steps in time order and `[k] bool`.
    """
    ape, keyframe = np.asarray(ape), np.asarray(keyframe, bool)
    if ape.shape != keyframe.shape or ape.ndim != 1:
        raise ValueError(f"pick_frames: ape and keyframe must both be [T], got {ape.shape} and {keyframe.shape}")
    picked: list[int] = []
    is_key: list[bool] = []

    def take(candidates, want, key):
        taken = 0
        for i in candidates:
            if taken == want:
                break
            if all(abs(int(i) - j) >= min_gap for j in picked):
                picked.append(int(i))
                is_key.append(key)
                taken += 1

    by_ape = np.argsort(-ape, kind="stable")
    take(by_ape[keyframe[by_ape]], count, True)
    calm = np.argsort(ape, kind="stable")
    take(calm[~keyframe[calm] & (calm >= skip_start)], ordinary, False)
    order = np.argsort(picked, kind="stable")
    return np.asarray(picked, int)[order], np.asarray(is_key, bool)[order]


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """`[start, stop)` of each run of True in `mask`."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def zoom_window(steps: int, center: int, width: int) -> tuple[int, int]:
    """`[start, stop)` of `width` steps (at most `steps`) centred on `center`, inside `[0, steps)`."""
    width = max(1, min(width, steps))
    start = min(max(center - width // 2, 0), steps - width)
    return start, start + width


def draw(ape: np.ndarray, actions: np.ndarray, threshold: float, frames: np.ndarray, frame_t: np.ndarray, *,
         keyframe: np.ndarray | None = None, title: str = "", note: str = "",
         action_names: list[str] | None = None, frame_is_key: np.ndarray | None = None,
         window: tuple[int, int] | None = None):
    """The keyframe picture of one episode, as a `matplotlib.figure.Figure` (no pyplot state).

    Rows: APE along the whole episode; the APE and the actions over `window`
    (the whole episode when `window` is None or covers it; otherwise a zoom,
    shaded grey in the first row); the frames, lettered as on the time axes.

    Args:
      ape: `[T]` APE of the episode's steps, normalised (1 = the dataset mean).
      actions: `[T, A]` the expert's actions.
      threshold: the keyframe threshold on `ape` (a dashed line).
      frames: `[k, H, W, 3] uint8` rendered frames, `k >= 0`.
      frame_t: `[k] int` the steps they show.
      keyframe: `[T] bool` which steps are keyframes (default: `ape >= threshold`).
      title: the figure's title; `note` a smaller line below it.
      action_names: `A` legend labels (default: `a0, a1, ...`).
      frame_is_key: `[k] bool` whether each frame is a keyframe (default: from `keyframe`).
      window: `(start, stop)` steps to show the actions over.

    Returns:
      The figure; save it with `save_png`.
    """
    from matplotlib.figure import Figure

    ape = np.asarray(ape, float)
    actions = np.asarray(actions, float)
    frames, frame_t = np.asarray(frames), np.asarray(frame_t, int)
    steps = ape.shape[0]
    if ape.ndim != 1 or actions.ndim != 2 or actions.shape[0] != steps:
        raise ValueError(f"draw: ape must be [T] and actions [T, A], got {ape.shape} and {actions.shape}")
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or frame_t.shape != frames.shape[:1]:
        raise ValueError(f"draw: frames must be [k, H, W, 3] uint8 with frame_t [k], got {frames.shape} "
                         f"{frames.dtype} and {frame_t.shape}")
    keyframe = ape >= threshold if keyframe is None else np.asarray(keyframe, bool)
    frame_is_key = keyframe[frame_t] if frame_is_key is None else np.asarray(frame_is_key, bool)
    names = action_names or [f"a{i}" for i in range(actions.shape[1])]
    start, stop = (0, steps) if window is None else (max(0, window[0]), min(steps, window[1]))
    zoomed = (start, stop) != (0, steps)
    letters = [chr(ord("A") + i) if i < 26 else str(i) for i in range(len(frame_t))]
    log_ape = _spans_decades(ape)

    heights = [2.4, 1.1, 1.6, 2.7] if zoomed else [2.4, 1.6, 2.7]
    fig = Figure(figsize=(12, 9.6 if zoomed else 8.4), layout="constrained")
    rows = fig.add_gridspec(len(heights), 1, height_ratios=heights if len(frames) else [*heights[:-1], 0.01])
    ax_ape = fig.add_subplot(rows[0])
    _plot_ape(ax_ape, ape, keyframe, threshold, 0, steps, log_ape, legend=True)
    if zoomed:
        ax_ape.axvspan(start - 0.5, stop - 0.5, color="0.5", alpha=0.15, lw=0)
        ax_ape.set_xlabel(f"step t in the episode (grey band: steps {start}-{stop - 1}, shown close up below)",
                          labelpad=1)
        ax_zoom = fig.add_subplot(rows[1])
        _plot_ape(ax_zoom, ape, keyframe, threshold, start, stop, log_ape, legend=False)
        ax_zoom.tick_params(labelbottom=False)
    ax_act = fig.add_subplot(rows[2 if zoomed else 1], sharex=ax_zoom if zoomed else ax_ape)
    if not zoomed:
        ax_ape.tick_params(labelbottom=False)
    t = np.arange(start, stop)
    for run_start, run_stop in _runs(keyframe[start:stop]):
        ax_act.axvspan(start + run_start - 0.5, start + run_stop - 0.5, color=KEY_COLOR, alpha=0.18, lw=0)
    for i in range(actions.shape[1]):
        ax_act.plot(t, actions[start:stop, i], lw=1.0, label=names[i], marker="." if stop - start <= 300 else None, ms=2.5)
    ax_act.set_ylabel("expert action")
    ax_act.set_xlabel("step t in the episode")
    ax_act.set_xlim(start - 0.5, stop - 0.5)
    ax_act.legend(loc="upper left", fontsize=8, ncol=len(names), framealpha=0.9)

    time_axes = [ax_ape, ax_zoom, ax_act] if zoomed else [ax_ape, ax_act]
    for letter, ft, key in zip(letters, frame_t, frame_is_key):
        color = KEY_COLOR if key else ORDINARY_COLOR
        for ax in time_axes:
            if ax is ax_ape or start <= ft < stop:
                ax.axvline(ft, color=color, lw=1, ls=":", alpha=0.9)
        for ax in time_axes[:-1]:
            if ax is ax_ape or start <= ft < stop:
                ax.annotate(letter, (ft, 1.0), xycoords=("data", "axes fraction"), xytext=(0, 2),
                            textcoords="offset points", ha="center", va="bottom", fontsize=10,
                            fontweight="bold", color=color)

    if len(frames):
        cells = rows[-1].subgridspec(1, max(len(frames), 4))
        for i, (frame, letter, ft, key) in enumerate(zip(frames, letters, frame_t, frame_is_key)):
            ax = fig.add_subplot(cells[i])
            ax.imshow(frame, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            color = KEY_COLOR if key else ORDINARY_COLOR
            for spine in ax.spines.values():
                spine.set_color(color)
                spine.set_linewidth(2.5)
            kind = "keyframe" if key else "ordinary step"
            ax.set_title(f"{letter}: t = {ft}, APE {_number(ape[ft])} × mean\n{kind}", fontsize=9, color=color)
    if title:
        fig.suptitle(title + (f"\n{note}" if note else ""), fontsize=11)
    return fig


def _number(value: float) -> str:
    return f"{value:,.0f}" if abs(value) >= 100 else f"{value:.2g}"


def _spans_decades(ape: np.ndarray) -> bool:
    positive = ape[ape > 0]
    return bool(positive.size) and positive.max() / max(np.percentile(positive, 5), 1e-12) > 100


def _plot_ape(ax, ape, keyframe, threshold, start, stop, log, legend):
    t = np.arange(start, stop)
    part, key = ape[start:stop], keyframe[start:stop]
    ax.plot(t, part, color="0.35", lw=0.7 if stop - start > 300 else 1.0, label="APE / dataset mean")
    ax.scatter(t[key], part[key], s=9 if stop - start > 300 else 16, color=KEY_COLOR, zorder=3,
               label=f"keyframes ({int(key.sum())} of {stop - start} steps)")
    if np.isfinite(threshold):
        ax.axhline(threshold, color=KEY_COLOR, ls="--", lw=1, label=f"keyframe threshold ({threshold:.2g})")
    if log:  # spikes span decades: a log axis keeps the calm stretches readable
        ax.set_yscale("log")
        ax.set_ylim(bottom=max(np.percentile(ape[ape > 0], 1) / 2, 1e-4))
    ax.set_ylabel("APE (÷ mean)")
    ax.set_xlim(start - 0.5, stop - 0.5)
    if legend:
        ax.legend(loc="upper left", fontsize=8, ncol=3, framealpha=0.9)


def save_png(fig, path: pathlib.Path, dpi: int = 120) -> int:
    """Writes `fig` to `path` as a PNG atomically (temporary file, then renamed); returns its size in bytes."""
    from ape_jax import data

    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data.write_atomic(path, lambda f: fig.savefig(f, format="png", dpi=dpi))
    return path.stat().st_size


# -- the command --------------------------------------------------------------------------------

def action_names(env) -> list[str] | None:
    """Actuator names of a MuJoCo environment (else their joints' names), or ToyCar's (throttle, brake)."""
    if env.name == "toycar":
        return ["throttle", "brake"]
    try:
        model = env.brax_env.sys.mj_model
    except AttributeError:
        return None
    names = []
    for i in range(model.nu):
        joint = model.joint(int(model.actuator(i).trnid[0])).name.removesuffix("_joint")
        names.append(model.actuator(i).name or joint or f"a{i}")
    return names


def main(argv=None) -> int:
    args = parse(argv)
    import jax
    import jax.numpy as jnp

    import envs
    from ape_jax import ape as ape_lib
    from ape_jax import collect, data
    from envs.experts import ExpertError
    from experiments.weights import fit_ape

    started = time.perf_counter()
    try:
        cfg = collect.settings(args.env, demo_obs(args.env), collect.default_episodes(args.env), seed=0)
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

    ape_raw = fit_ape(demos, args.ape_steps, args.seed)
    try:
        ape_all, _, scale = ape_lib.normalize(ape_raw, ape_raw[:0], "mean")
    except ValueError as e:
        return fail(None, f"{path}: {e}")
    ape_all = np.asarray(ape_all)
    is_key, threshold = keyframe_mask(ape_all, args.thr)
    rows = np.flatnonzero(np.asarray(demos.episode) == args.episode)
    ape_ep, key_ep, actions = ape_all[rows], is_key[rows], np.asarray(demos.action)[rows]
    min_gap = args.min_gap or max(1, len(rows) // (2 * (args.frames + args.ordinary)))
    frame_t, frame_key = pick_frames(ape_ep, key_ep, args.frames, min_gap, args.ordinary, skip_start=ape_lib.K)

    env = envs.make(args.env, obs="image", image_size=args.image_size)
    sims = jax.tree.map(lambda x: jnp.asarray(np.asarray(x)[rows[frame_t]]), demos.sim)
    frames = np.asarray(jax.jit(jax.vmap(env.observe_sim))(sims)) if len(frame_t) else np.zeros((0, 1, 1, 3), np.uint8)

    n_key = int(key_ep.sum())
    title = (f"{args.env} expert, episode {args.episode}: {n_key} of {len(rows)} steps ({n_key / len(rows):.0%}) "
             f"are keyframes")
    note = (f"keyframes = top {args.thr:.0%} APE over all {len(demos):,} steps of the {demos.num_episodes} "
            f"demonstrations (APE model fitted on all of them, {args.ape_steps} Adam steps; APE ÷ its mean {scale:.3g})")
    window = None
    if 0 < args.zoom and 2 * args.zoom <= len(rows) and frame_key.any():
        window = zoom_window(len(rows), int(frame_t[frame_key][np.argmax(ape_ep[frame_t[frame_key]])]), args.zoom)
    fig = draw(ape_ep, actions, threshold, frames, frame_t, keyframe=key_ep, title=title, note=note,
               action_names=action_names(env), frame_is_key=frame_key, window=window)
    try:
        size = save_png(fig, args.out)
    except OSError as e:
        return fail(None, f"--out {args.out}: cannot write ({e.strerror or e})")
    shown = ", ".join(f"t={t}{'*' if k else ''}" for t, k in zip(frame_t, frame_key))
    print(f"{args.out} ({size / 1024:.0f} KB)\n{args.env} episode {args.episode}: {n_key}/{len(rows)} keyframes "
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
