#!/usr/bin/env bash
# Perceive, then imitate (docs/perception.md): ToyTown's camera tables through the task's pretrained perception encoder
# (`--set recipe.perception=task`, envs/perception/toytown.npz, its card results/perception/toytown.json), at the state
# row's settings: the camera `default` preset (100 demonstrations, 10,000 updates of batch 64, Adam at 1e-3), 5 seeds,
# task version 2; the gate with 100 evaluation episodes per policy (the state row's), the tables with 25 (the camera
# tables' own: every step of a rollout renders and embeds a frame, and 100 episodes of 55 policies cost about three
# hours of one core, docs/speed.md).
#   1. the gates (docs/design.md, "Perception gates", fixed before this queue ran): BC-SO and BC-OH with the speed in
#      view; (b) BC-SO within 10 points of the one-frame state's BC-SO (results/toytown-pos-nocrash-default.json),
#      (c) BC-OH's embedding history reads a_{t-1} better than BC-SO's (its ctl ratio below 1);
#   2. the tables: the camera tables' 11 methods, speed in view (nocrash) and not (nocrash-nospeed).
# Two pieces side by side, each pinned to one core, lowest priority. Rerun to go on: a landed piece is skipped, a
# started one resumes from its checkpoints (in RUNS, this machine's). GATE_ONLY=1: the gate piece alone; TABLES_ONLY=1: the tables alone.
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/toytown-perceived}
PY=${PY:-$WT/.venv/bin/python}
METHODS=bc-so,bc-oh,ours-step,fca,history-dropout,dagger,boosting,rap,palr,mine,bc-full
cd "$WT" || exit 2
mkdir -p "$RUNS/exploratory"
source "$WT/results/queue/_lib.sh"
camera=(--env toytown --obs image --preset default --quiet --set recipe.perception=task)
gate=("exploratory/toytown-perceived-gate ${camera[*]} --protocol nocrash --methods bc-so,bc-oh --set budget.eval_episodes=100")
tables=()
for protocol in nocrash nocrash-nospeed; do
  tables+=("toytown-perceived-$protocol-default ${camera[*]} --protocol $protocol --methods $METHODS")
done
if [ "${TABLES_ONLY:-0}" = 1 ]; then pool "${tables[@]}"; exit $?; fi
# the gate again with the second encoder (gaps regressed as exp(-x/10), results/perception/toytown.json): BC-SO alone
# (gate (c) held with the first, results/exploratory/toytown-perceived-gate.json)
if [ "${GATE2_ONLY:-0}" = 1 ]; then
  piece exploratory/toytown-perceived-gate-near "${CORE:-0}" "${camera[@]}" --protocol nocrash --methods bc-so \
    --set budget.eval_episodes=100
  exit $?
fi
if [ "${GATE_ONLY:-0}" = 1 ]; then pool "${gate[@]}"; exit $?; fi
pool "${gate[@]}" "${tables[@]}"
