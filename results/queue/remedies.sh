#!/usr/bin/env bash
# Issue 59's ranking of the four remedies after the paper (channel-dropout, ptp, action-chunks, priming) beside the
# other methods, in both families of the report's ranking, with each cell's rows, seeds, budget and recipe (the
# `default` budget, the `bn-mlp` recipe; 5 seeds, 8 on FCA's expert): where copying is expected (the previous action
# in view; FCA's expert with raw and with clipped labels; the three rough experts) and the default tasks (the
# shipped SAC experts). Priming reads the sweep's own BC-SO (priming.source=bc-so), so each file trains BC-SO too:
# the same runs as the cell's committed BC-SO, and the file's own no-history control. ChannelDropout runs where a
# leaking channel is in view (the previous action); elsewhere it has nothing to drop. Import FCA's expert first:
#   python -m experiments.import_expert PATH/TO/fighting-copycat-agents/data/experts/Hopper-v1.pkl --env hopper --name cs294
# Two pieces side by side, each pinned to one core, at the lowest priority (`pool`). Waits for any sweep already
# running on the machine; resumable (rerun to go on).
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/remedies}
PY=${PY:-$WT/.venv/bin/python}
cd "$WT" || exit 2
mkdir -p "$RUNS"
source "$WT/results/queue/_lib.sh"
while pgrep -f "experiments.sweep" > /dev/null; do sleep 120; done   # one queue at a time on the 2 cores
SETTING="--protocol mujoco-state --recipe bn-mlp --preset default --quiet"
REMEDIES=bc-so,ptp,action-chunks,priming
NAME=pos-mujoco-state-rows-default-bn-mlp
PREV=hopper-$NAME-prevaction-remedies
ROUGH="--set protocol.expert=rough --set protocol.labels=raw"
# where copying is expected first, the previous action in view (ChannelDropout drops it) before all; then the
# default tasks
specs=("$PREV --env hopper $SETTING --seeds 5 --methods $REMEDIES,channel-dropout --set protocol.prev_action=true"
       "hopper-$NAME-cs294-raw-remedies --env hopper $SETTING --seeds 8 --methods $REMEDIES --set protocol.expert=cs294 --set protocol.labels=raw"
       "hopper-$NAME-cs294-clipped-remedies --env hopper $SETTING --seeds 8 --methods $REMEDIES --set protocol.expert=cs294")
for env in hopper walker2d halfcheetah; do
  specs+=("$env-$NAME-rough-raw-remedies --env $env $SETTING --seeds 5 --methods $REMEDIES $ROUGH")
done
for env in hopper walker2d halfcheetah; do
  specs+=("$env-$NAME-remedies --env $env $SETTING --seeds 5 --methods $REMEDIES")
done
# two pieces at a time, one per core (`pool`: priming reads BC-SO's policies, so a piece is one process)
pool "${specs[@]}"
rc=$?
# its BC-SO sees the previous action too: judged against the cell's no-history control, as the cell's other files
judge_by "$PREV" hopper-pos-fca-rows-default-fca-bc
exit "$rc"
