"""Figures of the reproduction report, as PNG files: drawing primitives and the report's figures.

- `primitives`: `heatmap`, `bars`, `lines`, `keyframes` (plain numbers in, a `matplotlib.figure.Figure` out, no
  pyplot state) and `save_png` (atomic);
- `builders`: the report's figures from merged results (`grid_figure`, `returns_figure`, `curves_figure`,
  `weights_figure`, `copycat_map_figure`, `budget_figure`, `extended_map_figure`).

Both are re-exported here: `experiments.report.figures.save_png`, `experiments.report.figures.keyframes`, ...
"""

from experiments.report.figures.builders import (budget_figure, copycat_map_figure, curves_figure,
                                                 extended_map_figure, grid_figure, min_run, returns_figure,
                                                 weights_figure)
from experiments.report.figures.primitives import (COLUMNS, DPI, KEY_COLOR, ORDINARY_COLOR, Bars, Grid, Lines, bars,
                                                   grid_axes, heatmap, keyframes, lines, save_png)

__all__ = ["COLUMNS", "DPI", "KEY_COLOR", "ORDINARY_COLOR", "Bars", "Grid", "Lines", "bars", "budget_figure",
           "copycat_map_figure", "curves_figure", "extended_map_figure", "grid_axes", "grid_figure", "heatmap",
           "keyframes", "lines", "min_run", "returns_figure", "save_png", "weights_figure"]
