#!/usr/bin/env bash
# Table 5 with FCA's expert at the paper's budget (300k iterations, evaluated at 30k, 100k and 300k; 100 evaluation
# episodes): Hopper, the mujoco-state protocol and the bn-mlp recipe (FCA's code's), FCA's Hopper-v1.pkl (imported
# as cs294) with raw labels, BC-SO, BC-OH, ours (step THR 10% W 5), FCA (alpha 0.1) and PALR (its default setting),
# 8 seeds. Split by seeds into pieces of SEEDS_PER
# seeds (budget.first_seed; a seed's numbers are the same in any piece: tests/test_width.py), each short enough to
# finish inside one session, each committed as results/NAME-seedsK.json when it lands; the report merges them.
# Two processes, each pinned to one core with XLA single-threaded (1.5x one process of two threads on this
# 2-core CPU: docs/speed.md), at the lowest priority. Import FCA's expert once first (never committed):
#   python -m experiments.import_expert PATH/TO/fighting-copycat-agents/data/experts/Hopper-v1.pkl --env hopper --name cs294
# Rerun to go on: a finished piece is skipped, a started one resumes from its checkpoints (in RUNS, this machine's).
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/t5-300k}
PY=${PY:-$WT/.venv/bin/python}
SEEDS_PER=${SEEDS_PER:-2}
PORT=${PORT:-12391}
NAME=hopper-pos-mujoco-state-rows-paper-bn-mlp-cs294-raw
# the knobs by their former recipe names (a notice each), as the first piece started: recipe.fca_alphas also sets
# fca-ib's, which the settings record, so fca.alphas alone would not resume that piece's checkpoints
cd "$WT" || exit 2
mkdir -p "$RUNS"
source "$WT/results/queue/_lib.sh"
ARGS=(--env hopper --protocol mujoco-state --recipe bn-mlp --preset paper --methods bc-so,bc-oh,ours-step,fca,palr
      --set recipe.step_grid=0.1:5 --set recipe.fca_alphas=0.1 --set protocol.expert=cs294 --set protocol.labels=raw
      --seeds "$SEEDS_PER" --quiet)
for first in $(seq 0 "$SEEDS_PER" 7); do
  piece "$NAME-seeds$first" 0,1 "${ARGS[@]}" --set budget.first_seed="$first" || exit 1
done
