"""What every section shares: `Section` (what a section function returns), `Context` (what it reads), the cells.

A section function takes the `Context` and returns the report's sections of one kind, `list[Section]` (empty
when the results have nothing for it). Figures are drawn through `Context.figure`, which links them relative to
the page and keeps them in `Context.drawn`, so nothing is written until the caller writes them.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from collections.abc import Callable, Sequence

from matplotlib.figure import Figure

from ape_jax import tasks
from experiments.report.analysis import Interval, Merged, PolicyDiagnostics, Spread, percent


@dataclasses.dataclass(frozen=True)
class Section:
    """One part of a page: a heading, a one-line caption under it, and what follows.

    Attributes:
      title: the heading's text; "" for a caption without a heading.
      caption: one line under the heading; "" for none.
      body: the markdown after it, one line or block each (a table is one string that ends in a newline; "" is a
        blank line).
    """

    title: str
    caption: str = ""
    body: Sequence[str] = ()

    def lines(self, level: int = 2) -> list[str]:
        """The section as lines to join with newlines: heading (`level` `#`s), blank, caption, blank, body."""
        head = ["#" * level + f" {self.title}", ""] if self.title else []
        return head + ([self.caption, ""] if self.caption else []) + list(self.body)


@dataclasses.dataclass(frozen=True)
class Context:
    """What the section functions read.

    Attributes:
      merged: the results per group (`analysis.merge`).
      figure_dir: where the figures will be written; None draws none (the report says so).
      base: the folder the page's links are relative to.
      drawn: `{path: Figure}`, every figure drawn so far (shared by the contexts of one report's pages: a figure
        linked from two pages is drawn once).
    """

    merged: Merged
    figure_dir: pathlib.Path | None
    base: pathlib.Path
    drawn: dict = dataclasses.field(default_factory=dict)

    def link(self, path: str | os.PathLike) -> str:
        """`path` relative to the page's folder, with `/` separators."""
        return pathlib.Path(os.path.relpath(pathlib.Path(path).absolute(), self.base.absolute())).as_posix()

    def figure(self, name: str, alt: str, draw: Callable[[], Figure | None]) -> list[str]:
        """The image link (and a blank line) of `draw()`'s figure, to be written as `figure_dir/name`; nothing without
        a `figure_dir` (`draw` is then not called) or when `draw` returns None. Drawn once per report."""
        if self.figure_dir is None:
            return []
        path = pathlib.Path(self.figure_dir) / name
        if path not in self.drawn:
            self.drawn[path] = draw()
        return [] if self.drawn[path] is None else [f"![{alt}]({self.link(path)})", ""]

    def on(self, base: pathlib.Path) -> Context:
        """The same report's context for a page in folder `base`."""
        return dataclasses.replace(self, base=pathlib.Path(base))


def page_name(env: str, obs: str) -> str:
    """A task page's file name: `hopper-pos.md`."""
    return f"{env}-{obs}.md"


def page_title(env: str, obs: str) -> str:
    """A task page's title: "Hopper, `pos` observations"."""
    return f"{tasks.get(env).title}, `{obs}` observations"


def table(head: Sequence[str], rows: Sequence[Sequence[str]], align: str | int = 1) -> str:
    """A markdown table ending in a newline: `head` the headings, `rows` the cells; `align` one `l` (left) or `r`
    (right) per column, or the number of leading columns left-aligned (the rest, numbers, right)."""
    align = "l" * align + "r" * (len(head) - align) if isinstance(align, int) else align
    return "\n".join(["| " + " | ".join(head) + " |", "|" + "".join("---|" if a == "l" else "---:|" for a in align),
                      *("| " + " | ".join(row) + " |" for row in rows)]) + "\n"


# -- cells the sections share --------------------------------------------------------------------------------------

# What an interval over two seeds is marked with: Student's t at one degree of freedom multiplies the standard
# error by 12.7, so such an interval is honest but too wide to read much from.
WIDE = " (2 seeds: wide)"


def interval(low: float, high: float, n: int, fmt: str = ".1f", note: bool = True) -> str:
    """`"[49.5, 50.5]"`: a 95% interval over `n` seeds; "" below 2 seeds (one seed gives none, only `[x, x]`), and
    at 2 seeds marked `WIDE` (with `note`; a table that says so once in its seeds column passes False)."""
    if n < 2:
        return ""
    return f"[{low:{fmt}}, {high:{fmt}}]" + (WIDE if n == 2 and note else "")


def seeds_cell(n: int) -> str:
    """A table's seeds column: the count, marked where its row's intervals are over 2 seeds (`interval`)."""
    return f"{n} (intervals wide)" if n == 2 else str(n)


def plus_minus(mean: float, sd: float | None, fmt: str = ",.0f") -> str:
    """`"1,000 ± 8"`: a mean ± the sample sd over seeds; the mean alone where one seed gives no sd (None)."""
    return f"{mean:{fmt}}" if sd is None else f"{mean:{fmt}} ± {sd:{fmt}}"


def return_cell(row: dict | None) -> str:
    """`"1,000 ± 8 (50%)"`: a summary row's mean return ± sd over seeds, with its % of expert; "—" for None."""
    if row is None:
        return "—"
    norm = f" ({row['normalized_mean']:.0f}%)" if row.get("normalized_mean") is not None else ""
    return plus_minus(row["return_mean"], row["return_std"]) + norm


def norm_cell(row: dict | None) -> str:
    """A summary row's % of expert, `"50.0"`; "—" for None or where not recorded."""
    return "—" if row is None or row.get("normalized_mean") is None else f"{row['normalized_mean']:.1f}"


def pct_cell(cell, fmt: str = ".1f") -> str:
    """`"50.0 [49.5, 50.5]"`: a mean over seeds with its 95% t-interval (`RecipeCell`; the mean alone at one seed,
    the interval marked wide at two: `interval`); "—" for None."""
    if cell is None:
        return "—"
    return f"{cell.mean:{fmt}} {interval(cell.low, cell.high, len(cell.seeds), fmt)}".rstrip()


def diff_cell(ci: Interval | None, fmt: str = "+.1f", either: bool = False) -> str:
    """`"+20.0 [+19.5, +20.5]"`: a difference with its interval, bold where `significant` (with `either`, where it
    excludes 0 either way with ≥ 2 seeds per arm); "—" for None."""
    if ci is None:
        return "—"
    text = f"{ci.diff:{fmt}} {interval(ci.low, ci.high, min(ci.n_a, ci.n_b), fmt)}".rstrip()
    bold = significant(ci) or (either and min(ci.n_a, ci.n_b) >= 2 and ci.high < 0)
    return f"**{text}**" if bold else text


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


def significant(ci: Interval | None) -> bool:
    """Whether `ci` says its first arm is better: ≥ 2 seeds per arm and the interval above 0."""
    return ci is not None and min(ci.n_a, ci.n_b) >= 2 and ci.low > 0


def hparams_text(hparams) -> str:
    """`"thr 0.1, w 5"` from a dict or `(key, value)` pairs; "—" for none."""
    return ", ".join(f"{k} {v:g}" for k, v in dict(hparams).items()) or "—"


# How tables name a weighting's setting, per kind: `"THR 10% W 5"`, `"τ 0.2"`.
SETTING_WORDS = {"step": lambda hp: f"THR {percent(hp['thr'])} W {hp['w']:g}",
                 "softmax": lambda hp: f"τ {hp['tau']:g}"}


def expert_text(found: dict | None, protocol: dict) -> str:
    """Who demonstrated and what the labels are, for a provenance line: `"expert `hopper-cs294`, imported from a
    cs294-pickle file (SHA-256 `…`), from ORIGIN; labels raw"`, a shipped one by its folder and card's SHA-256.

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
    return text + ("; labels raw (the executed action clipped)" if labels == "raw"
                   else f"; labels {labels}" + (" to the action range" if labels == "clipped" else ""))


def figures_note(ctx: Context) -> list[Section]:
    """Where the figures went when the report draws none (printed without `--figures`); nothing otherwise."""
    if ctx.figure_dir is not None:
        return []
    return [Section("", "_Figures not drawn: printed without `--figures DIR`._")]
