#!/usr/bin/env bash
# After a results file lands in results/: regenerate what is generated from the committed results (the index,
# results/README.md; the report, BENCHMARKS.md's block, docs/results/ and figures/), so the tree is ready to commit:
#   results/queue/land.sh && git add results BENCHMARKS.md docs/results figures && git commit -m "Results: ..."
set -euo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
PY=${PY:-$WT/.venv/bin/python}
cd "$WT"
"$PY" -m experiments.results_index > /dev/null
"$PY" -m experiments.report results/*.json --out BENCHMARKS.md > /dev/null
echo "regenerated results/README.md, BENCHMARKS.md, docs/results/ and figures/"
