#!/usr/bin/env bash
# The supplement's driving Tables 1 and 2 on ToyTown (docs/tasks.md): NoCrash-Dense with the speed in view
# (protocol nocrash) and without it (nocrash-nospeed), ToyTown's default image preset, every method of the
# tables (BC-SO, BC-OH, ours at THR 10% W 5, FCA α 0.2, HistoryDropout 0.5, DAgger, Boosting, RAP, PALR, MINE and
# BC-full, the full-state ceiling), 5 seeds. Split by seeds into pieces of SEEDS_PER seeds (budget.first_seed; a
# seed's numbers are the same in any piece), each committed as results/NAME-seedsK.json when it lands; the report
# merges them. One process at the lowest priority (PROCESSES=2: two, each pinned to one core, for pieces of several
# seeds: a piece of one seed has one policy per method, which two processes cannot share).
#   results/queue/toytown-tables.sh                 # both tables, Table 1 first
#   TABLES=nocrash-nospeed results/queue/toytown-tables.sh
# Rerun to go on: a finished piece is skipped, a started one resumes from its checkpoints (in RUNS, this machine's).
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/toytown}
PY=${PY:-$WT/.venv/bin/python}
SEEDS=${SEEDS:-5}
SEEDS_PER=${SEEDS_PER:-1}
PORT=${PORT:-12393}
TABLES=${TABLES:-nocrash nocrash-nospeed}
PROCESSES=${PROCESSES:-1}
METHODS=bc-so,bc-oh,ours-step,fca,history-dropout,dagger,boosting,rap,palr,mine,bc-full
cd "$WT" || exit 2
mkdir -p "$RUNS"
for protocol in $TABLES; do
  name=toytown-image-$protocol-default
  args=(--env toytown --protocol "$protocol" --preset default --methods "$METHODS" --seeds "$SEEDS_PER" --quiet)
  for first in $(seq 0 "$SEEDS_PER" $((SEEDS - 1))); do
    piece=$name-seeds$first
    if [ -f "results/$piece.json" ]; then echo "skip $piece (results/$piece.json exists)"; continue; fi
    out=$RUNS/$piece
    if [ ! -f "$out/results.json" ]; then
      echo "start $piece $(date -u +%FT%TZ)"
      resume=(); [ -f "$out/checkpoints/sweep.json" ] && resume=(--resume)
      if [ "$PROCESSES" = 1 ]; then
        nice -n 19 "$PY" -m experiments.sweep "${args[@]}" --set budget.first_seed="$first" --out "$out" \
          "${resume[@]}" > "$RUNS/$piece.log" 2>&1
        rc=$?
      else
        for i in 1 0; do   # process 1 in the background; process 0 (which writes) in the foreground
          cmd=(taskset -c "$i" nice -n 19 env XLA_FLAGS="--xla_cpu_multi_thread_eigen=false" "$PY" -m experiments.sweep
               "${args[@]}" --set budget.first_seed="$first" --out "$out" "${resume[@]}"
               --coordinator "localhost:$PORT" --num-processes 2 --process-id "$i")
          if [ "$i" = 1 ]; then "${cmd[@]}" > "$RUNS/$piece.p1.log" 2>&1 & else "${cmd[@]}" > "$RUNS/$piece.log" 2>&1; fi
        done
        rc=$?; wait
      fi
      [ "$rc" -eq 0 ] || { echo "FAILED $piece (exit $rc; $RUNS/$piece.log)"; exit 1; }
    fi
    cp "$out/results.json" "results/$piece.json" && "$PY" -m experiments.results_index > /dev/null \
      && echo "done $piece $(date -u +%FT%TZ) (results/README.md regenerated)"
  done
done
