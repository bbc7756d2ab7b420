#!/usr/bin/env bash
# Driving's state row (docs/tasks.md, "The one-frame state"): the supplement's Tables 1 and 2 on ToyTown's one-frame
# state (`--obs pos`, task version 2: brake lights in view), and the one-frame ceiling before and after the brake
# lights. ToyTown's `pos` default preset: 100 demonstrations, 10,000 updates of batch 64, Adam at 1e-3, 100
# evaluation episodes per policy in the held-out layouts, 5 seeds.
#   1. the ceiling (results/exploratory/toytown-ceiling-*.json, summarised by experiments.toytown_ceiling into
#      results/exploratory/toytown-ceiling.json): BC-SO on the one-frame state at task versions 1 (no brake lights)
#      and 2, each alone and with the car ahead's true speed revealed (`protocol.reveal=lead_speed`);
#   2. the tables: the camera tables' 11 methods, speed in view (nocrash) and not (nocrash-nospeed);
#   3. the stride extra: BC-OH, ours and FCA with the history's two frames 0.5 s apart (`protocol.history_stride=5`),
#      judged against the table's BC-SO.
# Two pieces side by side, each pinned to one core (PARALLEL=1: one at a time on both), lowest priority. Rerun to go
# on: a landed piece is skipped, a started one resumes from its checkpoints (in RUNS, this machine's).
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/toytown-state}
PY=${PY:-$WT/.venv/bin/python}
METHODS=bc-so,bc-oh,ours-step,fca,history-dropout,dagger,boosting,rap,palr,mine,bc-full
cd "$WT" || exit 2
mkdir -p "$RUNS/exploratory"
source "$WT/results/queue/_lib.sh"
state=(--env toytown --obs pos --preset default --quiet)
ceiling=()
for version in 1 2; do
  ceiling+=("exploratory/toytown-ceiling-v$version ${state[*]} --protocol nocrash --methods bc-so --set protocol.task_version=$version"
            "exploratory/toytown-ceiling-v$version-lead-speed ${state[*]} --protocol nocrash --methods bc-so --set protocol.task_version=$version --set protocol.reveal=lead_speed")
done
tables=()
for protocol in nocrash nocrash-nospeed; do
  tables+=("toytown-pos-$protocol-default ${state[*]} --protocol $protocol --methods $METHODS")
done
strides=()
for protocol in nocrash nocrash-nospeed; do
  strides+=("toytown-pos-$protocol-stride5-default ${state[*]} --protocol $protocol --methods bc-oh,ours-step,fca --set protocol.history_stride=5")
done
pool "${ceiling[@]}" "${tables[@]}" "${strides[@]}"; rc=$?
"$PY" -m experiments.toytown_ceiling results/exploratory/toytown-ceiling-v*.json \
  --out results/exploratory/toytown-ceiling.json || rc=1
for protocol in nocrash nocrash-nospeed; do
  judge_by "toytown-pos-$protocol-stride5-default" "toytown-pos-$protocol-default"
done
exit "$rc"
