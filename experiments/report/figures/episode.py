"""The keyframe picture of one episode (`keyframes`): APE along time with its keyframes, the expert's actions, and
rendered frames. Drawn by `experiments.keyframes`; re-exported as `experiments.report.figures.keyframes`."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

KEY_COLOR, ORDINARY_COLOR = "#d62728", "#1f77b4"   # a keyframe's marks and an ordinary step's, on every row


def keyframes(ape: np.ndarray, actions: np.ndarray, threshold: float, frames: np.ndarray, frame_t: np.ndarray, *,
              keyframe: np.ndarray | None = None, title: str = "", note: str = "",
              action_names: list[str] | None = None, frame_is_key: np.ndarray | None = None,
              window: tuple[int, int] | None = None) -> Figure:
    """The keyframe picture of one episode: where the expert's actions change, APE is high.

    Rows, top to bottom:
    - the APE along the whole episode, keyframes marked in red and the
      keyframe threshold dashed;
    - the expert's actions over `window`, keyframes shaded, so one sees that
      keyframes are where the actions change. When `window` is a close-up
      (not None and not the whole episode), the APE over it comes first, and
      the window is shaded grey on the top row;
    - the frames, each labelled with its step and APE and lettered as on the
      time axes (red: keyframe; blue: ordinary step).

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
    ape = np.asarray(ape, float)
    actions = np.asarray(actions, float)
    frames, frame_t = np.asarray(frames), np.asarray(frame_t, int)
    steps = ape.shape[0]
    if ape.ndim != 1 or actions.ndim != 2 or actions.shape[0] != steps:
        raise ValueError(f"keyframes: ape must be [T] and actions [T, A], got {ape.shape} and {actions.shape}")
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or frame_t.shape != frames.shape[:1]:
        raise ValueError(f"keyframes: frames must be [k, H, W, 3] uint8 with frame_t [k], got {frames.shape} "
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
        ax_act.plot(t, actions[start:stop, i], lw=1.0, label=names[i], marker="." if stop - start <= 300 else None,
                    ms=2.5)
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


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """`[start, stop)` of each run of True in `mask`."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))
