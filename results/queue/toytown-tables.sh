#!/usr/bin/env bash
# The supplement's driving Tables 1 and 2 on ToyTown (docs/tasks.md): NoCrash-Dense with the speed in view
# (protocol nocrash) and without it (nocrash-nospeed), ToyTown's default image preset, every method of the
# tables (BC-SO, BC-OH, ours at THR 10% W 5, FCA α 0.2, HistoryDropout 0.5, DAgger, Boosting, RAP, PALR, MINE and
# BC-full, the full-state ceiling), 5 seeds. Split by seeds into pieces of one seed (budget.first_seed; a seed's
# numbers are the same in any piece), each committed as results/NAME-seedsK.json when it lands; the report merges
# them. PARALLEL=2 (the default) runs two pieces side by side, each pinned to one core with XLA single-threaded (a
# piece of one seed has one policy per method, which two processes cannot share); PARALLEL=1 one piece on both
# cores. Lowest priority either way.
#   results/queue/toytown-tables.sh                 # both tables, Table 1 first
#   TABLES=nocrash-nospeed results/queue/toytown-tables.sh
# Rerun to go on: a finished piece is skipped, a started one resumes from its checkpoints (in RUNS, this machine's).
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/toytown}
PY=${PY:-$WT/.venv/bin/python}
SEEDS=${SEEDS:-5}
TABLES=${TABLES:-nocrash nocrash-nospeed}
PARALLEL=${PARALLEL:-2}
METHODS=bc-so,bc-oh,ours-step,fca,history-dropout,dagger,boosting,rap,palr,mine,bc-full
cd "$WT" || exit 2
mkdir -p "$RUNS"
source "$WT/results/queue/_lib.sh"
pieces=()   # "protocol first" for every piece not yet landed, Table 1 first
for protocol in $TABLES; do
  for first in $(seq 0 $((SEEDS - 1))); do
    if [ -f "results/toytown-image-$protocol-default-seeds$first.json" ]; then
      echo "skip toytown-image-$protocol-default-seeds$first (landed)"; else pieces+=("$protocol $first"); fi
  done
done
run() {  # run "PROTOCOL FIRST" CORES
  local protocol=${1% *} first=${1#* }
  piece "toytown-image-$protocol-default-seeds$first" "$2" --env toytown --protocol "$protocol" --preset default \
    --methods "$METHODS" --seeds 1 --set budget.first_seed="$first" --quiet
}
i=0
while [ "$i" -lt "${#pieces[@]}" ]; do
  if [ "$PARALLEL" = 2 ] && [ $((i + 1)) -lt "${#pieces[@]}" ]; then
    run "${pieces[$((i + 1))]}" 1 & other=$!
    run "${pieces[$i]}" 0; rc=$?
    wait "$other" || rc=1
    i=$((i + 2))
  else
    run "${pieces[$i]}" all; rc=$?
    i=$((i + 1))
  fi
  [ "$rc" -eq 0 ] || exit 1
done
