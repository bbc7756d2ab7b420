#!/usr/bin/env bash
# Issue 59's on-policy check: DAgger (online: it queries the expert on its own rollouts) and HistoryDropout (p 0.5)
# in every cell of the copycat family, with the cell's rows, seeds, budget and recipe, each file judged against the
# cell's own BC-SO (judge_by) so the report ranks them beside the cell's other methods. If DAgger clears BC-OH
# where the previous action is in view, the cell is sound and the offline remedies fail there. (The driving
# tables, results/queue/toytown-tables.sh, run both methods already.) Import FCA's expert once first:
#   python -m experiments.import_expert PATH/TO/fighting-copycat-agents/data/experts/Hopper-v1.pkl --env hopper --name fca
# Waits for any sweep already running on the machine; resumable (rerun to go on).
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/onpolicy}
PY=${PY:-$WT/.venv/bin/python}
cd "$WT" || exit 2
mkdir -p "$RUNS"
source "$WT/results/queue/_lib.sh"
while pgrep -f "experiments.sweep" > /dev/null; do sleep 120; done   # one queue at a time on the 2 cores
FCA="--protocol fca --recipe fca --preset default --methods dagger,history-dropout"
# the previous action in view (Hopper, the shipped SAC expert), 5 seeds: the one cell where policies copy
sweep hopper-pos-fca-rows-default-fca-prevaction-onpolicy --env hopper $FCA --seeds 5 --set protocol.prev_action=true
judge_by hopper-pos-fca-rows-default-fca-prevaction-onpolicy hopper-pos-fca-rows-default-fca-bc
# FCA's expert, raw and clipped labels, 8 seeds
sweep hopper-pos-fca-rows-default-fca-fcaexpert-raw-onpolicy --env hopper $FCA --seeds 8 \
  --set protocol.expert=fca --set protocol.labels=raw
judge_by hopper-pos-fca-rows-default-fca-fcaexpert-raw-onpolicy hopper-pos-fca-rows-default-fca-fcaexpert-raw
sweep hopper-pos-fca-rows-default-fca-fcaexpert-clipped-onpolicy --env hopper $FCA --seeds 8 --set protocol.expert=fca
judge_by hopper-pos-fca-rows-default-fca-fcaexpert-clipped-onpolicy hopper-pos-fca-rows-default-fca-fcaexpert-clipped
# the three rough experts (raw labels), 5 seeds
for env in hopper walker2d halfcheetah; do
  sweep $env-pos-fca-rows-default-fca-rough-raw-onpolicy --env $env $FCA --seeds 5 \
    --set protocol.expert=rough --set protocol.labels=raw
  judge_by $env-pos-fca-rows-default-fca-rough-raw-onpolicy $env-pos-fca-rows-default-fca-rough-raw
done
