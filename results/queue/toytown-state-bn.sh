#!/usr/bin/env bash
# FCA and MINE in a normalised network (an extra beside the state row's Table 1, results/queue/toytown-state.sh):
# under the shared `mlp` recipe both diverge on ToyTown's one-frame state (the adversary's or the estimator's term
# grows without bound through the encoder's scale, the BC loss reaches 10^3-10^4, the policies stand still). The
# FCA code's own encoder has BatchNorm: the same recipe with `recipe.network=bn-mlp` (nothing else changed), BC-OH
# beside them as the reference in the same network, 5 seeds, 100 held-out episodes. One piece on both cores, into
# results/exploratory/ (another network: not one of the tables' groups).
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/toytown-state}
PY=${PY:-$WT/.venv/bin/python}
cd "$WT" || exit 2
mkdir -p "$RUNS/exploratory"
source "$WT/results/queue/_lib.sh"
piece exploratory/toytown-pos-nocrash-bn-default all --env toytown --obs pos --preset default --quiet --protocol nocrash \
  --methods bc-so,bc-oh,fca,mine --set recipe.network=bn-mlp
