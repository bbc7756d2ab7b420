#!/usr/bin/env bash
# Issue 59's on-policy check: DAgger (online: it queries the expert on its own rollouts) and HistoryDropout (p 0.5)
# in every cell of the copycat family, with the cell's rows, seeds, budget and recipe, each file judged against the
# cell's own BC-SO (judge_by) so the report ranks them beside the cell's other methods. If DAgger clears BC-OH
# where the previous action is in view, the cell is sound and the offline remedies fail there. (The driving
# tables, results/queue/toytown-tables.sh, run both methods already.) Import FCA's expert once first:
#   python -m experiments.import_expert PATH/TO/fighting-copycat-agents/data/experts/Hopper-v1.pkl --env hopper --name cs294
# Waits for any sweep already running on the machine; resumable (rerun to go on).
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/onpolicy}
PY=${PY:-$WT/.venv/bin/python}
cd "$WT" || exit 2
mkdir -p "$RUNS"
source "$WT/results/queue/_lib.sh"
while pgrep -f "experiments.sweep" > /dev/null; do sleep 120; done   # one queue at a time on the 2 cores
SETTING="--protocol mujoco-state --recipe bn-mlp --preset default --methods dagger,history-dropout"
# the previous action in view (Hopper, the shipped SAC expert), 5 seeds: the one cell where policies copy
sweep hopper-pos-mujoco-state-rows-default-bn-mlp-prevaction-onpolicy --env hopper $SETTING --seeds 5 --set protocol.prev_action=true
judge_by hopper-pos-mujoco-state-rows-default-bn-mlp-prevaction-onpolicy hopper-pos-fca-rows-default-fca-bc
# FCA's expert, raw and clipped labels, 8 seeds
sweep hopper-pos-mujoco-state-rows-default-bn-mlp-cs294-raw-onpolicy --env hopper $SETTING --seeds 8 \
  --set protocol.expert=cs294 --set protocol.labels=raw
judge_by hopper-pos-mujoco-state-rows-default-bn-mlp-cs294-raw-onpolicy hopper-pos-fca-rows-default-fca-fcaexpert-raw
sweep hopper-pos-mujoco-state-rows-default-bn-mlp-cs294-clipped-onpolicy --env hopper $SETTING --seeds 8 --set protocol.expert=cs294
judge_by hopper-pos-mujoco-state-rows-default-bn-mlp-cs294-clipped-onpolicy hopper-pos-fca-rows-default-fca-fcaexpert-clipped
# the three rough experts (raw labels), 5 seeds
for env in hopper walker2d halfcheetah; do
  sweep $env-pos-mujoco-state-rows-default-bn-mlp-rough-raw-onpolicy --env $env $SETTING --seeds 5 \
    --set protocol.expert=rough --set protocol.labels=raw
  judge_by $env-pos-mujoco-state-rows-default-bn-mlp-rough-raw-onpolicy $env-pos-fca-rows-default-fca-rough-raw
done
