"""The report's pages: `build` runs the section functions of each page and joins what they return.

- the findings' block (`SUMMARY`), which `--out` (BENCHMARKS.md) holds between `<!-- report:start -->` and
  `<!-- report:end -->`: the headline tables;
- `index.md` in the pages folder: the headline (`LEAD`: the paper's budget beside Table 5, then driving), the task
  pages listed, then every table across tasks (`ACROSS`);
- one page per task and observation mode, `ENV-OBS.md` (`page_name`): per group, every configuration, its files'
  provenance, the loss analysis and the diagnostics (`detail.group_sections`), and the task's own metrics.

Each section is a function `(Context) -> list[Section]` (`experiments.report.sections`). `build` writes nothing.
"""

from __future__ import annotations

import pathlib
from collections.abc import Callable, Sequence
from typing import NamedTuple

from matplotlib.figure import Figure

from ape_jax.pipeline import results as results_lib
from experiments.report.analysis import check_references, merge, ordered
from experiments.report.sections import (copycat, curves, detail, differences, driving, ranking, recipe, regime,
                                         state, task_metrics)
from experiments.report.sections.common import Context, Section, figures_note, page_name, page_title, table

# The findings' block: the headline tables.
SUMMARY: tuple[Callable[[Context], list[Section]], ...] = (
    recipe.budget_summary,                # the paper's budget beside Table 5, with the differences
    regime.regime_summary,                # Table 5 with FCA's expert, returns only
    ranking.ranking_section,              # the later methods ranked with the paper's
    ranking.onpolicy_section,             # the on-policy check where copying is expected
    copycat.copycat_map_section,          # the copycat map per frame skip
)

# `index.md` opens with the headline: the paper's protocol, recipe and budget beside Table 5 (what BENCHMARKS.md's
# first table and the README's answer read), then driving, before the list of task pages.
LEAD: tuple[Callable[[Context], list[Section]], ...] = (
    recipe.paper_budget_section,          # the paper's budget over training, beside Table 5
    driving.driving_lead,                 # per driving task, the verdict, a figure and its pages
)

# `index.md` after the list of task pages: the tables across tasks, in order.
ACROSS: tuple[Callable[[Context], list[Section]], ...] = (
    state.state_sections,                 # MuJoCo-State per protocol, with Table 5
    recipe.recipe_section,                # the paper's recipe: mlp against bn-mlp
    regime.regime_section,                # Table 5 with FCA's expert (an expert of FCA's kind, labels raw or clipped)
    ranking.ranking_section,              # the later methods ranked with the paper's
    ranking.onpolicy_section,             # the on-policy check where copying is expected
    copycat.copycat_map_section,          # the copycat map per frame skip
    copycat.extended_map_section,         # where copycat appears: the map, extended
    state.image_sections,                 # MuJoCo-Image
    differences.differences_section,      # BC-OH − BC-SO and Ours − BC-OH with Welch t-intervals
    differences.longer_section,           # training longer
    curves.sensitivity_section,           # the supplement's §4
    curves.curves_and_weights_section,    # training curves and weights within a batch
)

INDEX = "index.md"


class Page(NamedTuple):
    """One generated page: its title (the file's `#` heading, written once when the file is new) and its markdown."""

    title: str
    text: str


class Built(NamedTuple):
    """What `build` returns: the findings' block, the pages by file name (`index.md` first) and the figures to
    write (`{path: Figure}`, for `experiments.report.figures.save_png`)."""

    summary: str
    pages: dict[str, Page]
    figures: dict[pathlib.Path, Figure]

    @property
    def text(self) -> str:
        """Everything as one markdown text: the block, then each page under its title (what printing shows)."""
        return "\n".join([self.summary, *(f"# {p.title}\n\n{p.text}" for p in self.pages.values())])


def _join(sections: list[Section], level: int = 2) -> str:
    text = "".join(line + "\n" for s in sections for line in s.lines(level))
    return text.rstrip("\n") + "\n\n" if text else ""   # a blank line before whatever follows


def build(files: Sequence[results_lib.Results], figure_dir: pathlib.Path | None = None,
          base: pathlib.Path | None = None, pages: pathlib.Path | None = None) -> Built:
    """The report's block and pages, and its figures, nothing written.

    Args:
      files: loaded results files (`experiments.report.load`).
      figure_dir: where the figures will be written; None draws none (the text says so).
      base: the folder the block's links are relative to (the `--out` file's); default the working folder.
      pages: the folder of the pages, their links relative to it; default `base`.

    Raises:
      ReportError: files that cannot be merged, or a file judged by its return without expert references (its tables
        are in % of expert: `check_references`).
    """
    for res in files:
        check_references(res)
    base = pathlib.Path.cwd() if base is None else pathlib.Path(base)
    ctx = Context(merge(files), None if figure_dir is None else pathlib.Path(figure_dir), base)
    here = ctx.on(base if pages is None else pathlib.Path(pages))
    keys: dict[tuple[str, str], list] = {}
    for key, _ in ordered(ctx.merged):
        keys.setdefault((key.env, key.obs), []).append(key)
    out: dict[str, Page] = {}
    for (env, obs), group in keys.items():
        sections = [s for key in group for s in task_metrics.task_metric_sections(here, key)]
        sections += [s for key in group for s in detail.group_sections(here, key)]
        out[page_name(env, obs)] = Page(page_title(env, obs),
                                        f"Every configuration, by protocol; across tasks: [the results]({INDEX}).\n\n"
                                        + _join(sections))
    listed = table(["page", "groups", "results files"],
                   [[f"[{p.title}]({name})", str(len(group)), str(len({s.path for k in group
                                                                       for s in ctx.merged[k].sources}))]
                     for (name, p), group in zip(out.items(), keys.values())])
    index = [s for fn in (figures_note, *LEAD) for s in fn(here)]
    index += [Section("Every task's page", "Per task, every configuration and where it came from; the tables across "
                      "tasks follow.", [listed])]
    index += [s for fn in ACROSS for s in fn(here)]
    summary = _join([s for fn in SUMMARY for s in fn(ctx)], level=3)
    summary += f"Every table: [the results]({ctx.link(here.base / INDEX)}).\n"
    return Built(summary, {INDEX: Page("Results", _join(index)), **out},
                 {path: fig for path, fig in ctx.drawn.items() if fig is not None})
