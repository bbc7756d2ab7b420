"""Figures of the reproduction report, as PNG files: drawing primitives and the report's figures.

- `primitives`: `heatmap`, `bars`, `interval_bars`, `lines` (plain numbers in, a `matplotlib.figure.Figure` out, no
  pyplot state, at most `MAX_HEIGHT` pixels tall) and `save_png` (atomic);
- `episode`: `keyframes`, the keyframe picture of one episode (`experiments.keyframes`);
- `families`: which groups one figure draws together (`families`, `panel_title`): one figure per question;
- `builders`: the report's figures of returns, grids, curves, weights and the ranking (`grid_figure`,
  `returns_figure`, `curves_figure`, `weights_figure`, `ranking_figure`);
- `copycat`: the copycat figures (`copycat_map_figure`, `budget_figure`, `extended_map_figure`), with the copycat
  verdicts' thresholds drawn (`verdict_thresholds`);
- `driving`: the driving tables' figure (`driving_figure`: success and stuck per method, the supplement's Tables 1
  and 2).

All are re-exported here: `experiments.report.figures.save_png`, `experiments.report.figures.keyframes`, ...
"""

from experiments.report.figures.builders import (TRAINED_ON, curves_figure, grid_figure, ranking_figure,
                                                 returns_figure, returns_groups, weights_figure)
from experiments.report.figures.copycat import (MAP_AXES, budget_figure, copycat_map_figure, extended_map_figure,
                                                min_run, verdict_thresholds)
from experiments.report.figures.driving import DRIVING_PANELS, driving_figure
from experiments.report.figures.episode import KEY_COLOR, ORDINARY_COLOR, keyframes
from experiments.report.figures.families import FAMILIES, Family, families, family_of, panel_title
from experiments.report.figures.primitives import (COLUMNS, DPI, MAX_HEIGHT, Bars, Grid, Intervals, Lines, bars,
                                                   fit_rows, grid_axes, heatmap, interval_bars, lines, save_png, wrap)

__all__ = ["COLUMNS", "DPI", "DRIVING_PANELS", "FAMILIES", "KEY_COLOR", "MAP_AXES", "MAX_HEIGHT", "ORDINARY_COLOR",
           "TRAINED_ON", "Bars", "Family", "Grid", "Intervals", "Lines", "bars", "budget_figure", "copycat_map_figure",
           "curves_figure", "driving_figure", "interval_bars",
           "extended_map_figure", "families", "family_of", "fit_rows", "grid_axes", "grid_figure", "heatmap",
           "keyframes", "lines", "min_run", "panel_title", "ranking_figure", "returns_figure", "returns_groups",
           "save_png", "verdict_thresholds", "weights_figure", "wrap"]
