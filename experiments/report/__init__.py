"""Tables and figures for BENCHMARKS.md:
`python -m experiments.report RESULTS... [--out BENCHMARKS.md] [--figures DIR]`.

Reads `results.json` files written by `experiments.sweep` and merges them per
task, observation mode and protocol (several files of one group are joined,
e.g. the main grid and a `--methods baselines` run; schema 1 files, which
record no protocol, are `brax`). Results of one task under two protocols are
different experiments and never mix; nor do results of two experts (a shipped
variant by its name, an imported expert by its name and SHA-256) or of raw and
clipped labels. It prints, or with `--out` writes into
the file's `report` section (and rebuilds the file's table of contents, when it
has one between `<!-- toc:start -->` and `<!-- toc:end -->`: `experiments.report.toc`):

- MuJoCo-State per protocol: first the paper's (`fca`: frame skip 1, 500
  standard steps of simulated time), every method per task as return mean ±
  std over seeds and as a percentage of our expert (normalised against a
  random policy), with the supplement's Table 5 beside it on the same scale
  (absolute returns, the ratio to BC-OH secondary); then Brax's own settings
  (`brax`, the project's first results), compared with Table 5 by ratios to
  BC-OH only. The fca family's other frame skips (`fca-fs2`, `fca-fs4`) get
  no table of their own: they make the copycat map;
- Table 5 with FCA's expert: per group of an imported expert (FCA's own, named by its file's SHA-256) or raw
  labels (the rough experts of its kind) under the paper's protocol and recipe, every method in % of expert with
  its bootstrap interval beside the supplement's Table 5, its difference from BC-OH with a verdict, both copycat
  verdicts' counts and the control and predictability ratios, and the history's share of the gap to BC-full
  (absent while no such file is given);
- MuJoCo-Image and ToyCar's own metrics (the supplement's Table 4 protocol);
- the copycat map: per task, BC-SO, BC-OH and Ours in % of expert per frame
  skip of the fca family, what the history adds (BC-OH − BC-SO, with its CI)
  and BC-OH's gap to the expert, with a generated sentence on where the gap opens;
- per task and protocol, BC-OH − BC-SO and Ours − BC-OH with a 95% bootstrap
  confidence interval over seeds (the paper's step setting, and the best step
  and softmax settings, which are selected after the fact and so optimistic),
  with a verdict; then a plain reading, built from those numbers, of whether
  keyframe weighting fixes copycat where copycat exists (tasks with fca results);
- the sensitivity study, training curves, and how concentrated a batch's
  weights are on the raw APE (the official code's, our default) and on the APE
  ÷ its mean (the old default), with what each group trained on;
- per group, the full grid (every configuration), the loss analysis (the
  paper's Table 3), copycat diagnostics, and where each number came from
  (command, protocol, preset, seeds, commit, machine);
- figures (PNG): per group the grid search as heatmaps (step THR × W, softmax
  τ) with a sentence on whether the paper's choices are near the best, every
  method's return per group (`returns.png`), the copycat map
  (`copycat-map.png`), training curves and weights.

Figures go to `--figures DIR`, by default the folder `figures/` next to `--out`
(`BENCHMARKS.md` → `figures/grid-hopper.png`; a group under a protocol other
than `brax` appends it, `grid-hopper-fca-fs2.png`), and are linked with paths
relative to `--out`; printed to stdout without `--figures`, the report draws
none and says so. PNGs are written atomically, before the report section.

No number in these tables is typed by hand; regenerate them after every sweep.
Method labels come from what each results file records of its methods (a
plugin's too), then the method registry; tasks are told apart by their record
(`ape_jax.tasks`): one judged by a rate is reported in %.

The package: `analysis` (loading, merging per protocol, the rows each table
picks, the bootstrap, the copycat map, the weights: one module per concern),
`paper` (every number of the paper's the report sets beside ours), `sections`
(each section a function `(Context) -> list[Section]`: its tables, generated
sentences and figure links), `markdown` (`build`: the sections in order),
`figures` (drawing primitives and the report's figures), `stats` (the
cross-task estimators of `experiments.compare`) and `toc` (the file's table of
contents).

A results file that cannot be read, is not JSON, or lacks a field the tables
use (or has it with the wrong type), one judged by its return that records no
expert references (its % of expert cannot be given: `analysis.check_references`,
with how to add them), and an `--out` that cannot be written, are
refused with one line on stderr and exit status 2; `--out` is then left as it was
(so is `--figures`: a folder that cannot be written is refused before anything is drawn).
"""

from __future__ import annotations

import pathlib
import sys

from experiments._cli import Parser, fail, unwritable, unwritable_file
from experiments.report import toc
from experiments.report.analysis import (ReportError, bootstrap_difference, bootstrap_rows, copycat_map, load, merge,
                                         verdict, weight_shares)
from experiments.report.figures import save_png
from experiments.report.markdown import build
from experiments.report.sections.detail import provenance

__all__ = ["ReportError", "bootstrap_difference", "bootstrap_rows", "build", "copycat_map", "load", "main", "merge",
           "provenance", "report", "verdict", "weight_shares"]


def report(files: list, figure_dir: pathlib.Path | None = None, base: pathlib.Path | None = None) -> str:
    """`build`, then writes its figures (atomically); returns the markdown."""
    text, drawn = build(files, figure_dir, base)
    for path, fig in drawn.items():
        save_png(fig, path)
    return text


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.report", description=__doc__.split("\n\n")[0])
    p.add_argument("results", nargs="+", type=pathlib.Path, help="results.json files of experiments.sweep")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="write into this file's `report` section (BENCHMARKS.md) instead of printing")
    p.add_argument("--figures", type=pathlib.Path, default=None, metavar="DIR",
                   help="write the figures (PNG) here; default: `figures/` next to --out, none when printing")
    args = p.parse_args(argv)
    if args.out is not None:
        why = unwritable_file(args.out)
        if why is None and args.out.exists():
            try:
                args.out.read_text()
            except (OSError, UnicodeDecodeError) as e:
                why = f"it cannot be read as text ({e})"
        if why:
            fail(p, f"--out {args.out}: cannot write the report there: {why}")
    figure_dir = args.figures if args.figures is not None else (
        None if args.out is None else args.out.parent / "figures")
    if figure_dir is not None and (why := unwritable(figure_dir)):
        flag = f"--figures {args.figures}" if args.figures is not None else f"--out {args.out}"
        fail(p, f"{flag}: cannot write the figures to {figure_dir}: {why}")
    try:
        text, drawn = build([load(path) for path in args.results], figure_dir,
                            None if args.out is None else args.out.parent)
    except ReportError as e:
        return fail(p, str(e))
    log = sys.stdout if args.out is not None else sys.stderr   # stdout carries the markdown when printing
    for path, fig in drawn.items():
        try:
            size = save_png(fig, path)
        except OSError as e:
            return fail(p, f"cannot write {path}: {e}")
        print(f"wrote {path} ({size / 1024:.0f} KB)", file=log)
    if args.out is None:
        print(text)
        return 0
    from experiments._timing import splice_section, write_text_atomic

    try:
        # the report section, then the table of contents from the new file's headings: one write
        old = args.out.read_text() if args.out.exists() else None
        write_text_atomic(str(args.out), toc.refresh(splice_section(old, text, "report")))
    except (OSError, UnicodeDecodeError) as e:
        return fail(p, f"cannot write {args.out}: {e}")
    print(f"wrote the report section of {args.out} from {len(args.results)} results file(s)")
    return 0

