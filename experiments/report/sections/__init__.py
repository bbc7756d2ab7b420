"""The report's sections, one module per family; each section is a function `(Context) -> list[Section]`.

- `common`: `Section`, `Context` (with `Context.figure`), `table` and the cells the sections share;
- `state`: MuJoCo-State per protocol (with the rows against BC-OH and Table 5) and MuJoCo-Image;
- `task_metrics`: a task's own metrics (the supplement's Table 4 protocol; a driving group's as its Table 1 or 2,
  every method with its copycat verdicts, the paper's comparisons and a figure of success and stuck);
- `driving`: the results page's driving section (per driving task, its verdict, a figure and its pages);
- `recipe`: the paper's recipe (mlp against bn-mlp) and the paper's budget beside Table 5;
- `regime`: Table 5 with FCA's expert (an imported expert or raw labels), against BC-OH and with its diagnostics;
- `ranking`: the later methods (`analysis.LATER`) ranked with the paper's, per family of cells;
- `copycat`: the copycat map and the extended map;
- `differences`: the differences' table and training longer;
- `curves`: the sensitivity study, the training curves and the weights;
- `diagnostics`: the copycat diagnostics tables the other sections use;
- `detail`: per group, every configuration, the loss analysis and each file's provenance.

`experiments.report.markdown` puts them on pages. They state numbers in tables, with one-line captions; the
readings are hand-written beside them.
"""

from experiments.report.sections.common import Context, Section

__all__ = ["Context", "Section"]
