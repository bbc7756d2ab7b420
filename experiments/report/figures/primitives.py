"""Drawing primitives: annotated heatmaps, per-method bars, line panels, and `save_png`.

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
- `interval_bars(labels, panels)` — panels side by side (one per measure), a
  horizontal bar per method (mean) with its interval and every seed as a dot;
  trailing rows (a ceiling) can be set apart below a dashed line.
- `lines(panels)` — one panel per environment, a line per series (with a
  shaded ± band if given): training curves, weight distributions.
- `bars` and `lines` wrap their panels into rows of at most `columns` and stay
  within `MAX_HEIGHT` pixels (`fit_rows`); long panel titles are wrapped (`wrap`).

The keyframe picture of one episode is `episode.keyframes`.
"""

from __future__ import annotations

import math
import os
import pathlib
import textwrap
from typing import NamedTuple
from collections.abc import Sequence

import numpy as np
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter, NullLocator

from experiments.report.analysis.selection import thousands

DPI = 120
# Saved without the matplotlib version, so a regenerated figure is byte-identical across matplotlib upgrades
# that do not change the drawing.
_METADATA = {"Software": None}
COLUMNS = 4  # panels per row of the report's multi-panel figures
# The tallest figure, in pixels at `DPI`: a figure taller than a screen at the page's width cannot be read whole, so
# the report draws one figure per question and `fit_rows` lays panels out wider rather than taller.
MAX_HEIGHT = 1600


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
    natural = 0.8 * sum(widths) + 1.3 * len(panels) + 1.0
    width = max(5.0, natural)   # a grid of one cell still fits its title; empty margins either side take the rest
    margin = (width - natural) / 2
    title = wrap(title, width)
    note = wrap("solid box: best cell of the panel; dashed box: the paper's choice; cells: mean ± sd over seeds",
                width, 8)
    # a grid of one row is still as tall as its row label (wrapped to three lines): shorter, the label reaches past
    # the panel and constrained layout has no room left to keep the title off it
    fig = Figure(figsize=(width, 0.8 * max(height, 1.6) + 1.9 + 0.2 * title.count("\n") + 0.15 * note.count("\n")),
                 dpi=DPI, layout="constrained")
    sides = [margin] if margin > 0 else []
    grid = fig.add_gridspec(1, len(panels) + 1 + 2 * len(sides),
                            width_ratios=[*sides, *(0.8 * w + 1.3 for w in widths), 0.25, *sides])
    image = None
    for i, p in enumerate(panels):
        ax = fig.add_subplot(grid[0, i + len(sides)])
        mean, std = np.asarray(p.mean, float), np.asarray(p.std, float)
        image = ax.imshow(np.ma.masked_invalid(mean), cmap=cmap, norm=norm, aspect="equal")
        ax.set_facecolor("0.85")
        ax.set_xticks(range(len(p.cols)), labels=list(p.cols))
        ax.set_yticks(range(len(p.rows)) if any(p.rows) else [], labels=list(p.rows) if any(p.rows) else [])
        ax.set_xlabel(p.col_label)
        ax.set_ylabel(textwrap.fill(p.row_label, 14))
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
    cbar = fig.colorbar(image, cax=fig.add_subplot(grid[0, len(panels) + len(sides)]))
    cbar.set_label(unit + ("\n(white = BC-OH)" if cmap == "RdBu" else ""), fontsize=8)
    cbar.ax.tick_params(labelsize=7)
    fig.suptitle(title, fontsize=10)
    fig.supxlabel(note, fontsize=8, color="0.25")
    return fig


class Lines(NamedTuple):
    """One line panel: `series` of `(label, x, y, band)` or `(label, x, y, band, style)`, `band` the ± half-width
    around y, a tuple `(lower, upper)` of the band's edges, or None, `style` matplotlib line keywords (e.g.
    `{"ls": "--", "color": "C0"}`); a series whose label is "" stays out of the legend. `refs` are horizontal
    reference lines `(y, text)`, dashed and labelled at the panel's right edge (a verdict's threshold)."""

    title: str
    xlabel: str
    ylabel: str
    series: Sequence[tuple]
    log_x: bool = False
    log_y: bool = False
    xticks: Sequence[float] | None = None  # ticks at these x, labelled `30k`-style, instead of matplotlib's
    empty: str = "no data"                   # what a panel without series says
    refs: Sequence[tuple[float, str]] = ()


def fit_rows(n: int, columns: int | None, row_in: float, extra_in: float, min_row_in: float) -> tuple[int, int, float]:
    """How `n` panels fit within `MAX_HEIGHT`: `(columns, rows, row height in inches)`.

    Rows of at most `columns` panels (None: one row; as few rows as that allows, as evenly filled as can be) of
    `row_in` inches; where they would make the figure (plus
    `extra_in` inches of titles and legends) taller than `MAX_HEIGHT` pixels at `DPI`, the rows are shrunk, down to
    `min_row_in`, and past that the figure gets more columns: a figure taller than a screen cannot be read whole.
    """
    # the fewest rows, then the fewest empty cells in the last: 6 panels as 3 + 3, not 4 + 2
    cols = n if columns is None else min(range(1, max(1, min(columns, n)) + 1),
                                         key=lambda c: (math.ceil(n / c), math.ceil(n / c) * c - n))
    room = MAX_HEIGHT / DPI - extra_in
    while True:
        rows = math.ceil(n / cols)
        height = min(row_in, room / rows)
        if height >= min_row_in or cols >= n:
            return cols, rows, height
        cols += 1


def grid_axes(fig: Figure, n: int, columns: int | None, **kw) -> list:
    """`n` axes in rows of at most `columns` (None: one row), row-major; the unused cells of the last row removed."""
    cols = n if columns is None else max(1, min(columns, n))
    rows = math.ceil(n / cols)
    axes = list(fig.subplots(rows, cols, squeeze=False, **kw).ravel())
    for ax in axes[n:]:
        ax.remove()
    return axes[:n]


def wrap(title: str, width_in: float, fontsize: float = 10) -> str:
    """`title` broken into lines that fit a panel `width_in` inches wide at `fontsize` points (a long group title
    would run into its neighbour's)."""
    return "\n".join(textwrap.fill(line, max(12, int(width_in * 120 / fontsize)), break_on_hyphens=False)
                     for line in title.split("\n"))


def _suptitle(title: str, width_in: float) -> tuple[str, float]:
    """`title` wrapped to a figure `width_in` inches wide, and the inches its lines take (none for "")."""
    text = wrap(title, width_in) if title else ""
    return text, 0.2 * (text.count("\n") + 1) + 0.15 if text else 0.0


def _label_reference(ax, y: float, text: str) -> None:
    """Labels the reference line at `y` at the panel's right edge: above the line, or below it where the line runs
    along the panel's top (the text would cross the frame into the title)."""
    near_top = (ax.transScale + ax.transLimits).transform((1.0, y))[1] > 0.9
    ax.annotate(text, (1.0, y), xycoords=("axes fraction", "data"), xytext=(-3, -2 if near_top else 2),
                textcoords="offset points", ha="right", va="top" if near_top else "bottom", fontsize=7, color="0.25")


def _mantissa(v: float) -> float:
    return round(v / 10 ** math.floor(math.log10(v)), 6) if v > 0 else 0.0


def _plain_log_ticks(ax) -> None:
    """A log y axis labelled in plain numbers (`0.3`, `2`, not `3×10⁻¹`): every minor tick within a decade, else
    ticks at 1, 2 and 5 times the powers of ten."""
    low, high = ax.get_ylim()
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    if 0 < low and high / low < 10:   # past a factor of 3 every minor label crowds: 1, 2, 3 and 5 times 10^k only
        few = FuncFormatter(lambda v, _: f"{v:g}" if high / low < 3 or _mantissa(v) in (1, 2, 3, 5) else "")
        ax.yaxis.set_minor_formatter(few)
    else:
        ax.yaxis.set_major_locator(LogLocator(10, subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_minor_formatter(NullFormatter())
    ax.yaxis.set_major_formatter(plain)


def lines(panels: Sequence[Lines], title: str = "", columns: int | None = None, shared_legend: bool = False,
          size: tuple[float, float] = (4.2, 3.6)) -> Figure:
    """Line plots, in rows of at most `columns` panels (`fit_rows`), each `size` inches (width, height).

    With `shared_legend` the series are named once, below the panels (every panel then draws the same methods in
    the same colours); otherwise each panel has its own legend.
    """
    if not panels:
        raise ValueError("lines needs at least one panel")
    labels = list(dict.fromkeys(s[0] for p in panels for s in p.series if s[0])) if shared_legend else []
    legend_in = 0.25 * math.ceil(len(labels) / 4) + 0.2 if labels else 0.0
    title, title_in = _suptitle(title, size[0] * fit_rows(len(panels), columns, 0, 0, 0)[0])   # the narrowest
    extra = title_in + legend_in
    cols, rows, row_in = fit_rows(len(panels), columns, size[1], extra, 2.4)
    fig = Figure(figsize=(size[0] * cols, row_in * rows + extra), dpi=DPI, layout="constrained")
    handles: dict[str, object] = {}
    for ax, p in zip(grid_axes(fig, len(panels), cols), panels):
        for label, x, y, band, *style in p.series:
            x, y = np.asarray(x, float), np.asarray(y, float)
            # a panel's own legend wraps a long name to the panel (a setting's full name ran off the figure)
            shown = label if shared_legend or not label else wrap(label, 0.8 * size[0], 7)
            (line,) = ax.plot(x, y, lw=1.3, label=shown or "_nolegend_", **(style[0] if style else {}))
            if label:
                handles.setdefault(label, line)
            if isinstance(band, tuple):  # (lower, upper): an interval that need not be symmetric
                ax.fill_between(x, np.asarray(band[0], float), np.asarray(band[1], float), color=line.get_color(),
                                alpha=0.2, lw=0)
            elif band is not None:
                b = np.asarray(band, float)
                ax.fill_between(x, y - b, y + b, color=line.get_color(), alpha=0.2, lw=0)
        for y, _ in p.refs if p.series else ():
            ax.axhline(y, color="0.25", ls="--", lw=1, zorder=1)
        ax.set_xscale("log" if p.log_x else "linear")
        ax.set_yscale("log" if p.log_y else "linear")
        if p.log_y and p.series:
            _plain_log_ticks(ax)
        for y, text in p.refs if p.series else ():
            _label_reference(ax, y, text)
        if not p.series:
            ax.set_xticks([])
            ax.set_yticks([])
            ax.xaxis.set_minor_locator(NullLocator())
            ax.yaxis.set_minor_locator(NullLocator())
            ax.text(0.5, 0.5, p.empty, ha="center", va="center", transform=ax.transAxes, fontsize=8, color="0.4")
        elif p.xticks is not None:
            ax.set_xticks(list(p.xticks), labels=[thousands(x) for x in p.xticks])
            ax.xaxis.set_minor_locator(NullLocator())
        ax.set_title(wrap(p.title, size[0]), fontsize=10)
        ax.set_xlabel(p.xlabel, fontsize=9)
        ax.set_ylabel(p.ylabel, fontsize=9)
        ax.grid(color="0.9")
        ax.tick_params(labelsize=8)
        if not shared_legend and any(s[0] for s in p.series):
            ax.legend(fontsize=7, frameon=False)
    if labels:
        fig.legend([handles[k] for k in labels], labels, loc="outside lower center", ncol=min(4, len(labels)),
                   fontsize=8, frameon=False)
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def _finite(v) -> bool:
    return v is not None and math.isfinite(v)


def bars(labels: Sequence[str], panels: Sequence[Bars], title: str = "", columns: int | None = None) -> Figure:
    """Horizontal bars, one panel per group, methods on a shared vertical axis.

    A mean that is None or not finite is "not run"; an sd that is None or not finite (one seed) draws no error bar.

    Args:
      labels: the method names, top to bottom.
      panels: one per group; each aligned with `labels`.
      title: the figure's title.
      columns: panels per row (None: all in one row; more where `fit_rows` needs them); the method names label
        each row's first panel.

    Returns:
      The figure (Agg canvas), `DPI` dots per inch, at most `MAX_HEIGHT` pixels tall.
    """
    if not panels:
        raise ValueError("bars needs at least one panel")
    n = len(labels)
    title, extra = _suptitle(title, 3.3 * fit_rows(len(panels), columns, 0, 0, 0)[0] + 1.9)   # the narrowest
    cols, rows, row_in = fit_rows(len(panels), columns, 0.3 * n + 1.3, extra, 0.2 * n + 1.0)
    fig = Figure(figsize=(3.3 * cols + 1.9, row_in * rows + extra), dpi=DPI, layout="constrained")
    axes = grid_axes(fig, len(panels), cols, sharey=True)
    y = np.arange(n)
    for ax, p in zip(axes, panels):
        present = [i for i in range(n) if _finite(p.mean[i])]
        sd = [p.std[i] if _finite(p.std[i]) else 0.0 for i in range(n)]
        seeds = [[s for s in p.seeds[i] if _finite(s)] for i in range(n)]
        ax.barh([y[i] for i in present], [p.mean[i] for i in present], height=0.65, color="#9ecae1",
                edgecolor="#3182bd", zorder=2)
        ax.errorbar([p.mean[i] for i in present], [y[i] for i in present], xerr=[sd[i] for i in present],
                    fmt="none", ecolor="black", capsize=2.5, lw=1, zorder=3)
        for i in range(n):
            if seeds[i]:
                offsets = np.linspace(-0.18, 0.18, len(seeds[i])) if len(seeds[i]) > 1 else np.zeros(1)
                ax.scatter(seeds[i], y[i] + offsets, s=9, color="#08306b", zorder=4, linewidths=0)
        values = [v for i in present for v in (p.mean[i] - sd[i], p.mean[i] + sd[i], *seeds[i])]
        top = max([*values, p.reference or 0.0, 1.0])
        low = min([*values, 0.0])
        ax.set_xlim(low - 0.02 * (top - low), top + 0.3 * (top - low))
        for i in range(n):
            if i not in present:
                ax.text(0.02 * (top - low), y[i], "not run", va="center", fontsize=7, color="0.45")
            else:
                right = max([p.mean[i] + sd[i], *seeds[i]])
                text = f"{p.mean[i]:.0f}" + (f" ({p.notes[i]})" if p.notes[i] else "")
                ax.text(right + 0.02 * (top - low), y[i], text, va="center", fontsize=7)
        if p.reference is not None:
            ax.axvline(p.reference, color="0.4", ls="--", lw=1, zorder=1)
            ax.text(p.reference, -0.6, p.reference_label, ha="center", va="bottom", fontsize=7, color="0.3")
        ax.set_title(wrap(p.title, 3.3), fontsize=10)
        ax.set_xlabel(p.xlabel, fontsize=9)
        ax.grid(axis="x", color="0.9", zorder=0)
        ax.tick_params(labelsize=8)
    axes[0].set_yticks(y, labels=list(labels))
    axes[0].set_ylim(n - 0.5, -1.0)
    for ax in axes[cols::cols]:  # sharey hides the names on every panel but the first: show them on each row's
        ax.tick_params(labelleft=True)
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


class Intervals(NamedTuple):
    """One panel of `interval_bars`: per row (aligned with the figure's labels) the mean, its interval's ends and the
    seeds; a mean that is None or not finite is "not run"."""

    title: str
    xlabel: str
    mean: Sequence[float | None]
    low: Sequence[float | None]
    high: Sequence[float | None]
    seeds: Sequence[Sequence[float]]
    limits: tuple[float, float] | None = None  # the x axis' range (a rate in %: (0, 100)); None: the data's


def interval_bars(labels: Sequence[str], panels: Sequence[Intervals], title: str = "",
                  apart: int | None = None) -> Figure:
    """Horizontal bars with their intervals, the panels side by side on one shared vertical axis of rows.

    Args:
      labels: the rows' names (methods), top to bottom.
      panels: one per measure, each aligned with `labels`.
      title: the figure's title.
      apart: the rows from this index on are set apart: below a dashed line, after a gap, drawn grey and hatched (a
        reference such as the full state's ceiling); None: none.

    Returns:
      The figure (Agg canvas), `DPI` dots per inch, at most `MAX_HEIGHT` pixels tall.
    """
    if not panels or not labels:
        raise ValueError(f"interval_bars needs at least one panel and one row, got {len(panels)} and {len(labels)}")
    n = len(labels)
    width = 3.6 * len(panels) + 2.4
    title, extra = _suptitle(title, width)
    y = np.array([i + (0.7 if apart is not None and i >= apart else 0.0) for i in range(n)])
    fig = Figure(figsize=(width, min(0.3 * (y[-1] + 1) + 1.3 + extra, MAX_HEIGHT / DPI)), dpi=DPI,
                 layout="constrained")
    axes = grid_axes(fig, len(panels), None, sharey=True)
    for ax, p in zip(axes, panels):
        present = [i for i in range(n) if _finite(p.mean[i])]
        seeds = [[s for s in p.seeds[i] if _finite(s)] for i in range(n)]
        ends = [(p.low[i] if _finite(p.low[i]) else p.mean[i], p.high[i] if _finite(p.high[i]) else p.mean[i])
                if i in present else (0.0, 0.0) for i in range(n)]
        values = [v for i in present for v in (*ends[i], *seeds[i])]
        low, top = p.limits if p.limits is not None else (min([*values, 0.0]), max([*values, 1.0]))
        for i in present:
            aside = apart is not None and i >= apart
            ax.barh(y[i], p.mean[i], height=0.65, color="0.85" if aside else "#9ecae1",
                    edgecolor="0.35" if aside else "#3182bd", hatch="//" if aside else None, zorder=2)
            ax.errorbar(p.mean[i], y[i], xerr=[[p.mean[i] - ends[i][0]], [ends[i][1] - p.mean[i]]], fmt="none",
                        ecolor="black", capsize=2.5, lw=1, zorder=3)
            if seeds[i]:
                offsets = np.linspace(-0.18, 0.18, len(seeds[i])) if len(seeds[i]) > 1 else np.zeros(1)
                ax.scatter(seeds[i], y[i] + offsets, s=9, color="#08306b", zorder=4, linewidths=0)
            ax.text(max([ends[i][1], *seeds[i]]) + 0.02 * (top - low), y[i], f"{p.mean[i]:.1f}", va="center",
                    fontsize=7)
        for i in set(range(n)) - set(present):
            ax.text(low + 0.02 * (top - low), y[i], "not run", va="center", fontsize=7, color="0.45")
        if apart is not None and 0 < apart < n:
            ax.axhline((y[apart - 1] + y[apart]) / 2, color="0.4", ls="--", lw=1, zorder=1)
        ax.set_xlim(low - 0.02 * (top - low), top + 0.15 * (top - low))
        ax.set_xticks([t for t in ax.get_xticks() if low <= t <= top])   # the room for the values stays unticked
        ax.set_title(wrap(p.title, 3.6), fontsize=10)
        ax.set_xlabel(p.xlabel, fontsize=9)
        ax.grid(axis="x", color="0.9", zorder=0)
        ax.tick_params(labelsize=8)
    axes[0].set_yticks(y, labels=list(labels))
    axes[0].set_ylim(y[-1] + 0.5, -0.5)
    if title:
        fig.suptitle(title, fontsize=10)
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
