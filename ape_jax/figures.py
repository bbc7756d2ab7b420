"""Figures of the reproduction report: grid-search heatmaps and per-method bars, as PNG files.

Host-side plotting helpers for `experiments.report`. They take plain numbers
(means, stds, per-seed values), not results files, and build
`matplotlib.figure.Figure` objects directly, so no pyplot global state and no
display backend are involved (the Agg canvas renders the PNG). `save_png`
writes atomically: a temporary file in the same folder, then `os.replace`.

- `heatmap(title, panels, center)` — one row of annotated heatmaps (e.g. the
  step grid THR × W and the softmax τ values), one shared colour scale; with a
  `center` (BC-OH's value) the diverging colours show better / worse than it.
- `bars(labels, panels)` — one panel per environment, a horizontal bar per
  method (mean), error bar (std over seeds) and every seed as a dot.
"""

from __future__ import annotations

import math
import os
import pathlib
from typing import NamedTuple, Sequence

import numpy as np
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

DPI = 120
# Saved without the matplotlib version, so a regenerated figure is byte-identical across matplotlib upgrades
# that do not change the drawing.
_METADATA = {"Software": None}


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
                  "cells: mean ± std over seeds", fontsize=8, color="0.25")
    return fig


def bars(labels: Sequence[str], panels: Sequence[Bars], title: str = "") -> Figure:
    """Horizontal bars, one panel per environment, methods on a shared vertical axis.

    Args:
      labels: the method names, top to bottom.
      panels: one per environment; each aligned with `labels`.
      title: the figure's title.

    Returns:
      The figure (Agg canvas), about 120 dpi.
    """
    if not panels:
        raise ValueError("bars needs at least one panel")
    n = len(labels)
    fig = Figure(figsize=(3.3 * len(panels) + 1.9, 0.34 * n + 1.6), dpi=DPI)
    axes = fig.subplots(1, len(panels), sharey=True, squeeze=False)[0]
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
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


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
