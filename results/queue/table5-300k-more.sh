#!/usr/bin/env bash
# Issue 58's "then, if time allows": BC-full (the full-state ceiling) and ours with softmax weighting at the paper's
# τ 0.2 beside Table 5 with FCA's expert at 300k (results/queue/table5-300k.sh: the same setting, seeds and pieces;
# the report merges these files into its group). Two processes pinned one per core, at the lowest priority.
# Rerun to go on: a finished piece is skipped, a started one resumes from its checkpoints (in RUNS, this machine's).
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/t5-300k}
PY=${PY:-$WT/.venv/bin/python}
SEEDS_PER=${SEEDS_PER:-2}
PORT=${PORT:-12392}
NAME=hopper-pos-mujoco-state-rows-paper-bn-mlp-cs294-raw-more
cd "$WT" || exit 2
mkdir -p "$RUNS"
source "$WT/results/queue/_lib.sh"
ARGS=(--env hopper --protocol mujoco-state --recipe bn-mlp --preset paper --methods bc-full,ours-softmax
      --set ours-softmax.taus=0.2 --set protocol.expert=cs294 --set protocol.labels=raw --seeds "$SEEDS_PER" --quiet)
for first in $(seq 0 "$SEEDS_PER" 7); do
  piece "$NAME-seeds$first" 0,1 "${ARGS[@]}" --set budget.first_seed="$first" || exit 1
done
