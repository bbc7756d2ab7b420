"""Drawing primitives: annotated heatmaps, per-method bars, line panels and the keyframe picture, and `save_png`.

Host-side plotting helpers for `experiments.report` and `experiments.keyframes`. They take plain numbers
(means, stds, per-seed values), not results files, and build
`matplotlib.figure.Figure` objects directly, so no pyplot global state and no
display backend are involved (the Agg canvas renders the PNG). `save_png`
writes atomically: a temporary file in the same folder, then `os.replace`.

- `heatmap(title, panels, center)` — one row of annotated heatmaps (e.g. the
  step grid THR × W and the softmax τ values), one shared colour scale; with a
  `center` (BC-OH's value) the diverging colours show better / worse than it.
- `bars(labels, panels)` — one panel per environment, a horizontal bar per
  method (mean), error bar (std over seeds) and every seed as a dot.
- `lines(panels)` — one panel per environment, a line per series (with a
  shaded ± band if given): training curves, weight distributions.
- `bars` and `lines` wrap their panels into rows of at most `columns`.
- `keyframes(ape, actions, threshold, frames, frame_t, ...)` — one episode's
  APE along time with its keyframes, the expert's actions, and rendered frames.
"""

from __future__ import annotations

import math
import os
import pathlib
from typing import NamedTuple
from collections.abc import Sequence

import numpy as np
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import FuncFormatter, NullLocator

from experiments.report.analysis.selection import thousands

DPI = 120
# Saved without the matplotlib version, so a regenerated figure is byte-identical across matplotlib upgrades
# that do not change the drawing.
_METADATA = {"Software": None}
KEY_COLOR, ORDINARY_COLOR = "#d62728", "#1f77b4"
COLUMNS = 4  # panels per row of the report's multi-panel figures


class Grid(NamedTuple):
    """One heatmap panel: `mean[r, c]` ± `std[r, c]` (NaN where the configuration was not run).

    `best` and `marked` are `(row, col)` cells outlined solid (the panel's best) and dashed (e.g. the
    paper's choice), or None.
    """

    title: str
    row_label: str
    col_label: str
    rows: Sequence[str]
    cols: Sequence[str]
    mean: np.ndarray  # [R, C] float
    std: np.ndarray  # [R, C] float
    best: tuple[int, int] | None = None
    marked: tuple[int, int] | None = None


class Bars(NamedTuple):
    """One bar panel: per method (aligned with the figure's labels) the mean, std and seeds, or None if not run."""

    title: str
    xlabel: str
    mean: Sequence[float | None]
    std: Sequence[float | None]
    seeds: Sequence[Sequence[float]]
    notes: Sequence[str]  # text after the bar's value, e.g. the selected τ; "" for none
    reference: float | None = None  # a vertical line, e.g. the expert at 100%
    reference_label: str = ""


def heatmap(title: str, panels: Sequence[Grid], center: float | None, unit: str = "% of expert") -> Figure:
    """Annotated heatmaps side by side, cells of equal size, one colour scale.

    Args:
      title: the figure's title (one or two lines).
      panels: the heatmaps, left to right; at least one.
      center: the value drawn white (colours: blue above, red below, symmetric), or None for a
        sequential scale over the values.
      unit: the colour bar's label.

    Returns:
      The figure (Agg canvas), about 120 dpi.
    """
    if not panels:
        raise ValueError("heatmap needs at least one panel")
    values = np.concatenate([np.asarray(p.mean, float).ravel() for p in panels])
    values = values[np.isfinite(values)]
    if center is not None and math.isfinite(center):
        half = max(float(np.max(np.abs(values - center))) if values.size else 0.0, 1e-6)
        norm, cmap = Normalize(center - half, center + half), "RdBu"
    else:
        lo, hi = (float(values.min()), float(values.max())) if values.size else (0.0, 1.0)
        norm, cmap = Normalize(lo, hi if hi > lo else lo + 1.0), "viridis"
    widths = [len(p.cols) for p in panels]
    height = max(len(p.rows) for p in panels)
    fig = Figure(figsize=(0.8 * sum(widths) + 1.3 * len(panels) + 1.0, 0.8 * height + 1.9), dpi=DPI,
                 layout="constrained")
    grid = fig.add_gridspec(1, len(panels) + 1, width_ratios=[*widths, 0.2])
    image = None
    for i, p in enumerate(panels):
        ax = fig.add_subplot(grid[0, i])
        mean, std = np.asarray(p.mean, float), np.asarray(p.std, float)
        image = ax.imshow(np.ma.masked_invalid(mean), cmap=cmap, norm=norm, aspect="equal")
        ax.set_facecolor("0.85")
        ax.set_xticks(range(len(p.cols)), labels=list(p.cols))
        ax.set_yticks(range(len(p.rows)) if any(p.rows) else [], labels=list(p.rows) if any(p.rows) else [])
        ax.set_xlabel(p.col_label)
        ax.set_ylabel(p.row_label)
        ax.set_title(p.title, fontsize=10)
        for (r, c), m in np.ndenumerate(mean):
            if not math.isfinite(m):
                ax.text(c, r, "not run", ha="center", va="center", fontsize=7, color="0.3")
                continue
            dark = abs(norm(m) - 0.5) > 0.32
            s = std[r, c]
            ax.text(c, r, f"{m:.1f}" + (f"\n±{s:.1f}" if math.isfinite(s) else ""), ha="center", va="center",
                    fontsize=8, color="white" if dark else "black")
        for cell, style in ((p.marked, "--"), (p.best, "-")):
            if cell is not None:
                r, c = cell
                ax.add_patch(Rectangle((c - 0.47, r - 0.47), 0.94, 0.94, fill=False, lw=2.2, ls=style,
                                       edgecolor="black"))
    cbar = fig.colorbar(image, cax=fig.add_subplot(grid[0, -1]))
    cbar.set_label(unit + ("\n(white = BC-OH)" if cmap == "RdBu" else ""), fontsize=8)
    cbar.ax.tick_params(labelsize=7)
    fig.suptitle(title, fontsize=10)
    fig.supxlabel("solid box: best cell of the panel; dashed box: the paper's choice; "
                  "cells: mean ± sd over seeds", fontsize=8, color="0.25")
    return fig


class Lines(NamedTuple):
    """One line panel: `series` of `(label, x, y, band)` or `(label, x, y, band, style)`, `band` the ± half-width
    around y, a tuple `(lower, upper)` of the band's edges, or None, `style` matplotlib line keywords (e.g.
    `{"ls": "--", "color": "C0"}`); a series whose label is "" stays out of the legend."""

    title: str
    xlabel: str
    ylabel: str
    series: Sequence[tuple]
    log_x: bool = False
    log_y: bool = False
    xticks: Sequence[float] | None = None  # ticks at these x, labelled `30k`-style, instead of matplotlib's
    empty: str = "no data"                   # what a panel without series says


def grid_axes(fig: Figure, n: int, columns: int | None, **kw) -> list:
    """`n` axes in rows of at most `columns` (None: one row), row-major; the unused cells of the last row removed."""
    cols = n if columns is None else max(1, min(columns, n))
    rows = math.ceil(n / cols)
    axes = list(fig.subplots(rows, cols, squeeze=False, **kw).ravel())
    for ax in axes[n:]:
        ax.remove()
    return axes[:n]


def lines(panels: Sequence[Lines], title: str = "", columns: int | None = None) -> Figure:
    """Line plots, one panel per environment (a legend in each panel), in rows of at most `columns` panels."""
    if not panels:
        raise ValueError("lines needs at least one panel")
    cols = len(panels) if columns is None else max(1, min(columns, len(panels)))
    fig = Figure(figsize=(4.2 * cols, 3.6 * math.ceil(len(panels) / cols)), dpi=DPI, layout="constrained")
    for ax, p in zip(grid_axes(fig, len(panels), cols), panels):
        for label, x, y, band, *style in p.series:
            x, y = np.asarray(x, float), np.asarray(y, float)
            (line,) = ax.plot(x, y, lw=1.3, label=label or "_nolegend_", **(style[0] if style else {}))
            if isinstance(band, tuple):  # (lower, upper): an interval that need not be symmetric
                ax.fill_between(x, np.asarray(band[0], float), np.asarray(band[1], float), color=line.get_color(),
                                alpha=0.2, lw=0)
            elif band is not None:
                b = np.asarray(band, float)
                ax.fill_between(x, y - b, y + b, color=line.get_color(), alpha=0.2, lw=0)
        ax.set_xscale("log" if p.log_x else "linear")
        ax.set_yscale("log" if p.log_y else "linear")
        low, high = ax.get_ylim()
        if p.log_y and p.series and 0 < low and high / low < 10:  # within a decade: `0.3`, `1.5`, not `3×10⁻¹`
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        if not p.series:
            ax.set_xticks([])
            ax.set_yticks([])
            ax.xaxis.set_minor_locator(NullLocator())
            ax.yaxis.set_minor_locator(NullLocator())
        elif p.xticks is not None:
            ax.set_xticks(list(p.xticks), labels=[thousands(x) for x in p.xticks])
            ax.xaxis.set_minor_locator(NullLocator())
        if not p.series:
            ax.text(0.5, 0.5, p.empty, ha="center", va="center", transform=ax.transAxes, fontsize=8, color="0.4")
        ax.set_title(p.title, fontsize=10)
        ax.set_xlabel(p.xlabel, fontsize=9)
        ax.set_ylabel(p.ylabel, fontsize=9)
        ax.grid(color="0.9")
        ax.tick_params(labelsize=8)
        if p.series:
            ax.legend(fontsize=7, frameon=False)
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def bars(labels: Sequence[str], panels: Sequence[Bars], title: str = "", columns: int | None = None) -> Figure:
    """Horizontal bars, one panel per environment, methods on a shared vertical axis.

    Args:
      labels: the method names, top to bottom.
      panels: one per environment; each aligned with `labels`.
      title: the figure's title.
      columns: panels per row (None: all in one row); the method names label each row's first panel.

    Returns:
      The figure (Agg canvas), about 120 dpi.
    """
    if not panels:
        raise ValueError("bars needs at least one panel")
    n = len(labels)
    cols = len(panels) if columns is None else max(1, min(columns, len(panels)))
    rows = math.ceil(len(panels) / cols)
    fig = Figure(figsize=(3.3 * cols + 1.9, (0.34 * n + 1.2) * rows + 0.4), dpi=DPI)
    axes = grid_axes(fig, len(panels), cols, sharey=True)
    y = np.arange(n)
    for ax, p in zip(axes, panels):
        present = [i for i in range(n) if p.mean[i] is not None]
        ax.barh([y[i] for i in present], [p.mean[i] for i in present], height=0.65, color="#9ecae1",
                edgecolor="#3182bd", zorder=2)
        ax.errorbar([p.mean[i] for i in present], [y[i] for i in present],
                    xerr=[p.std[i] or 0.0 for i in present], fmt="none", ecolor="black", capsize=2.5, lw=1,
                    zorder=3)
        for i in range(n):
            seeds = list(p.seeds[i])
            if seeds:
                offsets = np.linspace(-0.18, 0.18, len(seeds)) if len(seeds) > 1 else np.zeros(1)
                ax.scatter(seeds, y[i] + offsets, s=9, color="#08306b", zorder=4, linewidths=0)
        values = [v for i in present for v in (p.mean[i] + (p.std[i] or 0.0), *p.seeds[i])]
        top = max([*values, p.reference or 0.0, 1.0])
        low = min([*values, 0.0])
        ax.set_xlim(low - 0.02 * (top - low), top + 0.3 * (top - low))
        for i in range(n):
            if p.mean[i] is None:
                ax.text(0.02 * (top - low), y[i], "not run", va="center", fontsize=7, color="0.45")
            else:
                right = max([p.mean[i] + (p.std[i] or 0.0), *p.seeds[i]])
                text = f"{p.mean[i]:.0f}" + (f" ({p.notes[i]})" if p.notes[i] else "")
                ax.text(right + 0.02 * (top - low), y[i], text, va="center", fontsize=7)
        if p.reference is not None:
            ax.axvline(p.reference, color="0.4", ls="--", lw=1, zorder=1)
            ax.text(p.reference, -0.6, p.reference_label, ha="center", va="bottom", fontsize=7, color="0.3")
        ax.set_title(p.title, fontsize=10)
        ax.set_xlabel(p.xlabel)
        ax.grid(axis="x", color="0.9", zorder=0)
        ax.tick_params(labelsize=8)
    axes[0].set_yticks(y, labels=list(labels))
    axes[0].set_ylim(n - 0.5, -1.0)
    for ax in axes[cols::cols]:  # sharey hides the names on every panel but the first: show them on each row's
        ax.tick_params(labelleft=True)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


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


def save_png(fig: Figure, path: str | os.PathLike) -> int:
    """Writes `fig` as a PNG at `path` atomically (temporary file in the same folder, then rename).

    Returns:
      The file's size in bytes.
    """
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        fig.savefig(tmp, format="png", dpi=DPI, metadata=_METADATA)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path.stat().st_size
