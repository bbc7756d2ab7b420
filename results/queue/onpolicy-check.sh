#!/usr/bin/env bash
# Issue 59's on-policy check: DAgger (online: it queries the expert on its own rollouts) and HistoryDropout (p 0.5)
# in every cell of the copycat family, with the cell's rows, seeds, budget and recipe, each file judged against the
# cell's own BC-SO (judge_by) so the report ranks them beside the cell's other methods. If DAgger clears BC-OH
# where the previous action is in view, the cell is sound and the offline remedies fail there. (The driving
# tables, results/queue/toytown-tables.sh, run both methods already.) Import FCA's expert once first:
#   python -m experiments.import_expert PATH/TO/fighting-copycat-agents/data/experts/Hopper-v1.pkl --env hopper --name cs294
# Two pieces side by side, each pinned to one core, at the lowest priority (`pool`). Waits for any sweep already
# running on the machine; resumable (rerun to go on).
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/onpolicy}
PY=${PY:-$WT/.venv/bin/python}
cd "$WT" || exit 2
mkdir -p "$RUNS"
source "$WT/results/queue/_lib.sh"
while pgrep -f "experiments.sweep" > /dev/null; do sleep 120; done   # one queue at a time on the 2 cores
SETTING="--protocol mujoco-state --recipe bn-mlp --preset default --methods dagger,history-dropout --quiet"
PREV=hopper-pos-mujoco-state-rows-default-bn-mlp-prevaction-onpolicy
RAW=hopper-pos-mujoco-state-rows-default-bn-mlp-cs294-raw-onpolicy
CLIPPED=hopper-pos-mujoco-state-rows-default-bn-mlp-cs294-clipped-onpolicy
rough() { echo "$1-pos-mujoco-state-rows-default-bn-mlp-rough-raw-onpolicy"; }
# two pieces at a time, one per core (`pool`); the previous action in view first: the one cell where policies copy
pool "$PREV --env hopper $SETTING --seeds 5 --set protocol.prev_action=true" \
     "$RAW --env hopper $SETTING --seeds 8 --set protocol.expert=cs294 --set protocol.labels=raw" \
     "$CLIPPED --env hopper $SETTING --seeds 8 --set protocol.expert=cs294" \
     "$(rough hopper) --env hopper $SETTING --seeds 5 --set protocol.expert=rough --set protocol.labels=raw" \
     "$(rough walker2d) --env walker2d $SETTING --seeds 5 --set protocol.expert=rough --set protocol.labels=raw" \
     "$(rough halfcheetah) --env halfcheetah $SETTING --seeds 5 --set protocol.expert=rough --set protocol.labels=raw"
rc=$?
# each file judged against its cell's own BC-SO (the files of the cell's other methods)
judge_by "$PREV" hopper-pos-fca-rows-default-fca-bc
judge_by "$RAW" hopper-pos-fca-rows-default-fca-fcaexpert-raw
judge_by "$CLIPPED" hopper-pos-fca-rows-default-fca-fcaexpert-clipped
for env in hopper walker2d halfcheetah; do judge_by "$(rough $env)" "$env-pos-fca-rows-default-fca-rough-raw"; done
exit "$rc"
