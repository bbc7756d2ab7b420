"""The report's markdown: `build` runs the section functions in report order and joins what they return.

Each section is a function `(Context) -> list[Section]` (`experiments.report.sections`): it reads the merged
results, formats its tables and sentences from `experiments.report.analysis`'s numbers, and asks the figure
builders (`experiments.report.figures`) for the figures it links. `build` writes nothing.
"""

from __future__ import annotations

import pathlib
from collections.abc import Callable, Sequence

from matplotlib.figure import Figure

from ape_jax.pipeline import results as results_lib
from experiments.report.analysis import ReportError, check_references, merge
from experiments.report.sections import (copycat, curves, detail, differences, ranking, recipe, regime, state,
                                        task_metrics)
from experiments.report.sections.common import Context, Section, figures_note

# The report's sections in order.
SECTIONS: tuple[Callable[[Context], list[Section]], ...] = (
    state.state_sections,                 # MuJoCo-State per protocol, with Table 5
    recipe.recipe_section,                # the paper's recipe: mlp against fca
    recipe.paper_budget_section,          # the paper's budget over training, beside Table 5
    regime.regime_section,                # Table 5 with FCA's expert (an expert of FCA's kind, labels raw or clipped)
    ranking.ranking_section,              # the later methods (RAP, PALR, MINE) ranked with the paper's
    copycat.extended_map_section,         # where copycat appears: the map, extended
    state.image_sections,                 # MuJoCo-Image
    task_metrics.task_metric_sections,    # a task's own metrics (the supplement's Table 4 protocol)
    figures_note,                         # printed without --figures: none drawn
    copycat.copycat_map_section,          # the copycat map per frame skip
    differences.differences_section,      # BC-OH − BC-SO and Ours − BC-OH with bootstrap intervals
    differences.plain_reading_section,    # does keyframe weighting help where the history does not?
    differences.longer_section,           # training longer
    curves.sensitivity_section,           # the supplement's §4
    curves.curves_and_weights_section,    # training curves and weights within a batch
    detail.group_sections,                # per group: every configuration, losses, diagnostics, provenance
)


def build(files: Sequence[results_lib.Results], figure_dir: pathlib.Path | None = None,
          base: pathlib.Path | None = None) -> tuple[str, dict[pathlib.Path, Figure]]:
    """The report's markdown and its figures, nothing written.

    Args:
      files: loaded results files (`experiments.report.load`).
      figure_dir: where the figures will be written; None draws none (the text says so).
      base: the folder the markdown's links are relative to (the `--out` file's); default the working folder.

    Returns:
      `(text, figures)`: the markdown, and `{path: matplotlib Figure}` to write with
      `experiments.report.figures.save_png`.

    Raises:
      ReportError: files that cannot be merged, a file judged by its return without expert references (its tables
        are in % of expert: `check_references`), or two figures for one path.
    """
    for res in files:
        check_references(res)
    ctx = Context(merge(files), None if figure_dir is None else pathlib.Path(figure_dir),
                  pathlib.Path.cwd() if base is None else pathlib.Path(base))
    lines: list[str] = []
    drawn: dict[pathlib.Path, Figure] = {}
    for section_fn in SECTIONS:
        for section in section_fn(ctx):
            lines += section.lines()
            for path, fig in section.figures.items():
                # one file per figure (`analysis.file_stem`): never let one group's overwrite another's
                if path in drawn:
                    raise ReportError(f"two of the report's figures would be written to {path}; pass fewer results "
                                      "files")
                drawn[path] = fig
    return "\n".join(lines), drawn
