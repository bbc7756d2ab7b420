"""Tables and figures from sweep results:
`python -m experiments.report results/*.json --out BENCHMARKS.md`.

Reads `results.json` files written by `experiments.sweep` and merges them per task, observation mode, protocol,
expert, labels and budget (several files of one group are joined; two groups never mix). With `--out FILE` it
writes three things, each only between its `<!-- report:start -->` and `<!-- report:end -->` markers, so the
hand-written text around them stays:

- FILE (BENCHMARKS.md): the headline tables (the paper's budget beside the supplement's Table 5, Table 5 with FCA's
  expert, the later methods ranked, the copycat map);
- `--pages DIR` (default `docs/results/` next to FILE), `index.md`: the paper's budget beside Table 5 first, then
  every table across tasks (MuJoCo-State per protocol beside Table 5, the recipes, the copycat maps, MuJoCo-Image,
  the differences over seeds, training longer, the sensitivity study, curves and weights);
- DIR/`ENV-OBS.md`, one page per task and observation mode (`hopper-pos.md`): per group every configuration, its
  files and the commands that wrote them (machine paths stripped), the paper's settings against the grid, the
  loss analysis and the copycat diagnostics; a task's own metrics first (a ToyTown group under `nocrash` or
  `nocrash-nospeed` as the supplement's Table 1 or 2, every method with its copycat verdicts and the paper's
  comparisons, its figure of success and stuck, and Table 3 for every method);
- the figures (PNG) in `--figures DIR` (default `figures/` next to FILE), linked relative to each page, written
  atomically before the pages.

Without `--out` it prints everything (figures only with `--figures`). No number in these tables is typed by hand:
regenerate them after every sweep. The tables state results; the readings are written by hand beside them and
held true by tests on `analysis`'s numbers.

The package: `analysis` (loading, merging, the rows each table picks, the differences, the copycat map, the weights),
`paper` (every number of the paper the report sets beside ours), `sections` (each a function
`(Context) -> list[Section]`), `markdown` (`build`: the block and the pages), `figures` (drawing primitives and the
report's figures) and `stats` (the cross-task estimators `experiments.compare` shares).

A results file that cannot be read, is not JSON, lacks a field the tables use (or has it with the wrong type), or
is judged by its return without expert references (`analysis.check_references`), and an `--out`, `--pages` or
`--figures` that cannot be written, are refused with one line on stderr and exit status 2, before anything is
written.
"""

from __future__ import annotations

import pathlib
import sys

from experiments._cli import Parser, fail, unwritable, unwritable_file
from experiments.report.analysis import (ReportError, mean_difference, difference_rows, copycat_map, load, merge,
                                         verdict, weight_shares)
from experiments.report.figures import save_png
from experiments.report.markdown import Built, build
from experiments.report.sections.detail import provenance

__all__ = ["Built", "ReportError", "mean_difference", "difference_rows", "build", "copycat_map", "load", "main",
           "merge", "provenance", "report", "verdict", "weight_shares"]


def report(files: list, figure_dir: pathlib.Path | None = None, base: pathlib.Path | None = None) -> str:
    """`build`, then writes its figures (atomically); returns the block and the pages as one markdown text."""
    built = build(files, figure_dir, base)
    for path, fig in built.figures.items():
        save_png(fig, path)
    return built.text


def _splice(path: pathlib.Path, text: str, title: str | None = None) -> str:
    """`path`'s text with its report section replaced by `text`; a new page starts with `# title`."""
    from experiments._timing import splice_section

    old = path.read_text() if path.exists() else (None if title is None else f"# {title}\n\n")
    return splice_section(old, text if text.endswith("\n") else text + "\n", "report")


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.report", description=__doc__.split("\n\n")[0])
    p.add_argument("results", nargs="+", type=pathlib.Path, help="results.json files of experiments.sweep")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="write the headline tables into this file's `report` section (BENCHMARKS.md), the pages and "
                        "the figures beside it; default: print everything")
    p.add_argument("--pages", type=pathlib.Path, default=None, metavar="DIR",
                   help="write the pages (index.md, ENV-OBS.md) here; default: docs/results/ next to --out")
    p.add_argument("--figures", type=pathlib.Path, default=None, metavar="DIR",
                   help="write the figures (PNG) here; default: figures/ next to --out, none when printing")
    args = p.parse_args(argv)
    if args.pages is not None and args.out is None:
        fail(p, f"--pages {args.pages}: give --out too (without it the report is printed)")
    if args.out is not None:
        why = unwritable_file(args.out)
        if why is None and args.out.exists():
            try:
                args.out.read_text()
            except (OSError, UnicodeDecodeError) as e:
                why = f"it cannot be read as text ({e})"
        if why:
            fail(p, f"--out {args.out}: cannot write the report there: {why}")
    pages = args.pages if args.pages is not None else (
        None if args.out is None else args.out.parent / "docs" / "results")
    if pages is not None and (why := unwritable(pages)):
        fail(p, f"--pages {pages}: cannot write the pages there: {why}")
    figure_dir = args.figures if args.figures is not None else (
        None if args.out is None else args.out.parent / "figures")
    if figure_dir is not None and (why := unwritable(figure_dir)):
        flag = f"--figures {args.figures}" if args.figures is not None else f"--out {args.out}"
        fail(p, f"{flag}: cannot write the figures to {figure_dir}: {why}")
    try:
        built = build([load(path) for path in args.results], figure_dir,
                      None if args.out is None else args.out.parent, pages)
    except ReportError as e:
        return fail(p, str(e))
    log = sys.stdout if args.out is not None else sys.stderr   # stdout carries the markdown when printing
    for path, fig in built.figures.items():
        try:
            size = save_png(fig, path)
        except OSError as e:
            return fail(p, f"cannot write {path}: {e}")
        print(f"wrote {path} ({size / 1024:.0f} KB)", file=log)
    if args.out is None:
        print(built.text)
        return 0
    from experiments._timing import write_text_atomic

    try:
        pages.mkdir(parents=True, exist_ok=True)
        for name, page in built.pages.items():
            write_text_atomic(str(pages / name), _splice(pages / name, page.text, page.title))
        write_text_atomic(str(args.out), _splice(args.out, built.summary))
    except (OSError, UnicodeDecodeError) as e:
        return fail(p, f"cannot write the report: {e}")
    print(f"wrote the report section of {args.out} and {len(built.pages)} pages in {pages} from "
          f"{len(args.results)} results file(s)")
    return 0
