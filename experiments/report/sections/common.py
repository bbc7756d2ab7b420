"""What every section shares: `Section` (what a section function returns), `Context` (what it reads), the cells.

A section function takes the `Context` and returns the report's sections of one kind, `list[Section]` (empty
when the results have nothing for it); `experiments.report.markdown.build` calls them in order and joins their
lines. Figures are drawn through `Context.figure`, which links them relative to the markdown and hands them back
with the section, so nothing is written until the caller writes them.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from typing import NamedTuple
from collections.abc import Callable, Mapping, Sequence

from matplotlib.figure import Figure

from experiments.report.analysis import Interval, Merged, PolicyDiagnostics, Spread, percent


@dataclasses.dataclass(frozen=True)
class Section:
    """One part of the report: a heading, the paragraph under it, what follows, and the figures it links.

    Attributes:
      title: the heading's text (written `### title`); "" for a paragraph without a heading.
      intro: the paragraph under the heading; "" for none.
      body: the markdown after it, one line or block each (a table is one string that ends in a newline; "" is a
        blank line).
      figures: `{path: Figure}` the body links, to write with `experiments.report.figures.save_png`.
    """

    title: str
    intro: str = ""
    body: Sequence[str] = ()
    figures: Mapping[pathlib.Path, Figure] = dataclasses.field(default_factory=dict)

    def lines(self) -> list[str]:
        """The section as the lines `build` joins with newlines: heading, blank, intro, blank, body."""
        head = [f"### {self.title}", ""] if self.title else []
        return head + ([self.intro, ""] if self.intro else []) + list(self.body)


class Drawn(NamedTuple):
    """A figure as a section links it: its markdown (the image link and a blank line; none when not drawn) and
    `{path: Figure}` (empty when not drawn)."""

    lines: list[str]
    figures: dict[pathlib.Path, Figure]


@dataclasses.dataclass(frozen=True)
class Context:
    """What the section functions read.

    Attributes:
      merged: the results per group (`analysis.merge`).
      figure_dir: where the figures will be written; None draws none (the report says so).
      base: the folder the markdown's links are relative to (the `--out` file's).
    """

    merged: Merged
    figure_dir: pathlib.Path | None
    base: pathlib.Path

    def figure(self, name: str, alt: str, draw: Callable[[], Figure | None]) -> Drawn:
        """`draw()`'s figure, to be written as `figure_dir/name`, linked with `alt`; nothing without a `figure_dir`
        (`draw` is then not called) or when `draw` returns None."""
        fig = draw() if self.figure_dir is not None else None
        if fig is None:
            return Drawn([], {})
        path = pathlib.Path(self.figure_dir) / name
        link = pathlib.Path(os.path.relpath(path.absolute(), self.base.absolute())).as_posix()
        return Drawn([f"![{alt}]({link})", ""], {path: fig})


# -- cells and phrases the sections share ----------------------------------------------------------------------

def return_cell(row: dict | None) -> str:
    """`"1,000 ± 8 (50%)"`: a summary row's mean return ± std over seeds, with its % of expert; "—" for None."""
    if row is None:
        return "—"
    norm = f" ({row['normalized_mean']:.0f}%)" if row.get("normalized_mean") is not None else ""
    return f"{row['return_mean']:,.0f} ± {row['return_std']:,.0f}{norm}"


def norm_cell(row: dict | None) -> str:
    """A summary row's % of expert, `"50.0"`; "—" for None or where not recorded."""
    return "—" if row is None or row.get("normalized_mean") is None else f"{row['normalized_mean']:.1f}"


def pct_cell(cell) -> str:
    """`"50.0 [49.5, 50.5]"`: a mean over seeds with its 95% bootstrap interval (`RecipeCell`); "—" for None."""
    return "—" if cell is None else f"{cell.mean:.1f} [{cell.low:.1f}, {cell.high:.1f}]"


def diff_cell(ci: Interval | None) -> str:
    """`"+20.0 [+19.5, +20.5]"`: a difference with its interval, bold where `significant`; "—" for None."""
    if ci is None:
        return "—"
    text = f"{ci.diff:+.1f} [{ci.low:+.1f}, {ci.high:+.1f}]"
    return f"**{text}**" if significant(ci) else text


def ratio_text(s: Spread | None, with_range: bool = True) -> str:
    """`"0.412 (0.301–0.52)"`: a ratio's median over seeds and, with `with_range` and ≥ 2 seeds, their range."""
    if s is None:
        return "—"
    return f"{s.median:.3g}" + (f" ({s.low:.3g}–{s.high:.3g})" if with_range and s.n > 1 else "")


def copycat_count(d: PolicyDiagnostics) -> str:
    """`"0/5 (first verdict 2/5)"`: the seeds the controlled verdict judged copycat / the seeds it judged, the first
    verdict's count beside it; `"2/5 (first verdict only)"` where no seed has the controlled verdict (a file
    without a control); "—" where no seed could be read."""
    if not d.read:
        return "—"
    if not d.judged:
        return f"{d.copycats}/{d.read} (first verdict only)"
    return f"{d.controlled}/{d.judged} (first verdict {d.copycats}/{d.read})"


def verdict_count(d: PolicyDiagnostics) -> str:
    """`"copycat 0/5 (first verdict 2/5)"` (`copycat_count`); "—" where no seed could be read."""
    return "—" if not d.read else f"copycat {copycat_count(d)}"


def ci_text(ci: Interval, fmt: str = "+.1f") -> str:
    """`"95% CI [+1.0, +3.0]"`: an interval's bounds in format `fmt`."""
    return f"95% CI [{ci.low:{fmt}}, {ci.high:{fmt}}]"


def significant(ci: Interval | None) -> bool:
    """Whether `ci` says its first arm is better: ≥ 2 seeds per arm and the interval above 0."""
    return ci is not None and min(ci.n_a, ci.n_b) >= 2 and ci.low > 0


def lift(points: float, unit: str = "points of expert") -> str:
    """`"lifts BC-OH 12.3 points of expert above BC-SO"`, or `"leaves BC-OH 4.0 ... below BC-SO"` when negative."""
    if points >= 0:
        return f"lifts BC-OH {points:.1f} {unit} above BC-SO"
    return f"leaves BC-OH {-points:.1f} {unit} below BC-SO"


# How sentences name a weighting's setting, per kind: `"THR 10% W 5"`, `"τ 0.2"`.
SETTING_WORDS = {"step": lambda hp: f"THR {percent(hp['thr'])} W {hp['w']:g}",
                 "softmax": lambda hp: f"τ {hp['tau']:g}"}


def expert_text(found: dict | None, protocol: dict) -> str:
    """Who demonstrated and what the labels are, for a provenance line: `"expert `hopper-fca`, imported from a
    cs294-pickle file (SHA-256 `…`), from ORIGIN; labels raw (…)"`, a shipped one by its folder and card's SHA-256.

    Args:
      found: the file's demonstrator record (`analysis.demonstrator`), or None where it records none.
      protocol: the file's protocol (its `expert` variant and `labels`).
    """
    found = found or {}
    kind = found.get("kind")
    if kind == "imported":
        text = (f"expert `{found.get('name')}`, imported from a {found.get('format') or 'results'} file "
                f"(SHA-256 `{found.get('sha256')}`)" + (f", from {found['origin']}" if found.get("origin") else ""))
    elif kind == "checkpoint":
        text = (f"expert `{found.get('path')}`, shipped"
                + (f", {found['algorithm']}" if found.get("algorithm") else "")
                + (f", card SHA-256 `{found['card_sha256'][:12]}…`" if found.get("card_sha256") else ""))
    elif kind == "rule-based":
        text = "expert: the environment's own rule"
    else:
        text = f"expert `{protocol['expert']}`" if protocol.get("expert") else "the task's own expert"
    labels = protocol.get("labels") or "clipped"
    return text + ("; labels raw (the expert's output as it gave it; the executed action clipped to the action range)"
                   if labels == "raw" else f"; labels {labels} to the action range" if labels == "clipped"
                   else f"; labels {labels}")


def figures_note(ctx: Context) -> list[Section]:
    """Where the figures went when the report draws none (printed without `--figures`); nothing otherwise."""
    if ctx.figure_dir is not None:
        return []
    return [Section("", "_Figures not drawn: the report was printed without `--figures DIR` (with `--out` they go to "
                        "`figures/` next to it)._")]
