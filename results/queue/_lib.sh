# Shared by the queues (sourced): `piece NAME CORES ARGS...` runs one resumable sweep into $RUNS/NAME at the lowest
# priority on chosen cores and copies its results to results/NAME.json; `sweep NAME ARGS...` is a piece on every
# core whose failure does not stop the queue; `pool SPEC...` runs pieces two at a time, one per core; `judge_by NAME
# SIBLING` gives a file without a no-history control of its own the controlled verdict from SIBLING's BC-SO. All
# expect WT (the checkout, the working directory), RUNS and PY.
# Sweeps run the committed code of the moment they start, from a snapshot (`snapshot`): edits to the checkout while a
# sweep runs never reach it (a sweep imports some modules late, at its end), and its results record the commit
# that ran. Results land in the checkout (WT), which regenerates the index and report with its own code.

snapshot() {  # prints the snapshot of HEAD's committed code to run sweeps from, made once per commit in $RUNS/.code
  # (a detached git worktree, ~40 MB; snapshots over two days old are removed)
  local rev dir
  rev=$(git -C "$WT" rev-parse --short HEAD) || return 1
  dir=$RUNS/.code/$rev
  mkdir -p "$RUNS/.code"
  (  # one at a time: two pieces started together make the snapshot once
    flock 9
    [ -d "$dir" ] && exit 0
    find "$RUNS/.code" -mindepth 1 -maxdepth 1 -type d -mtime +2 -exec git -C "$WT" worktree remove --force {} \; \
      2> /dev/null
    git -C "$WT" worktree add --detach "$dir" HEAD > /dev/null 2>&1
  ) 9> "$RUNS/.code/.lock" || return 1
  echo "$dir"
}

wait_for() {  # wait_for OUT: a sweep running in OUT (started by an earlier queue, its folder locked) finishes first
  [ -f "$1/sweep.lock" ] || return 0
  flock -n "$1/sweep.lock" true || { echo "wait for the sweep running in $1"; flock "$1/sweep.lock" true; }
}

sweep() {  # sweep NAME ARGS...: one sweep into $RUNS/NAME on every core, its results to results/NAME.json (`piece`
  # with cores "all"); a failure is reported and the queue goes on
  piece "$1" all "${@:2}" || true
}

judge_by() {  # judge_by NAME SIBLING: results/NAME.json's controlled verdict from SIBLING's BC-SO, for a file with
  # none of its own (no BC-SO, or policies that see the previous action); idempotent, so rerun on every start.
  # --resampled: the sibling's demonstrations may be the same settings collected on another CPU (other bytes)
  [ -f "results/$1.json" ] || return
  "$PY" -m experiments.evaluate --rejudge "results/$1.json" --control "results/$2.json" --resampled > /dev/null \
    && echo "judged $1 against $2" || echo "FAILED judging $1 against $2"
}

piece() {  # piece NAME CORES ARGS...: one resumable sweep into $RUNS/NAME at the lowest priority, its results to
  # results/NAME.json (index and report regenerated, one landing at a time). CORES: "all" = one process on every
  # core; "0" or "1" = one process pinned to that core, XLA single-threaded (two pieces side by side); "0,1" = two
  # processes pinned one per core, coordinated on $PORT (1.5x one process of two threads: docs/speed.md)
  local name=$1 cores=$2; shift 2
  if [ -f "results/$name.json" ]; then echo "skip $name (results/$name.json exists)"; return 0; fi
  local out=$RUNS/$name rc=0
  mkdir -p "$(dirname "$out")" "$(dirname "results/$name")"  # a NAME may hold a folder (exploratory/...)
  wait_for "$out"
  if [ ! -f "$out/results.json" ]; then
    local src; src=$(snapshot) || { echo "FAILED $name (no code snapshot of $WT)"; return 1; }
    echo "start $name (cores $cores, code $(basename "$src")) $(date -u +%FT%TZ)"
    local resume=(); [ -f "$out/checkpoints/sweep.json" ] && resume=(--resume)
    local run=(nice -n 19 "$PY" -m experiments.sweep "$@" --out "$out" "${resume[@]}")
    local one=(env XLA_FLAGS="--xla_cpu_multi_thread_eigen=false" "${run[@]}")
    pushd "$src" > /dev/null || return 1
    case $cores in
      all) "${run[@]}" > "$RUNS/$name.log" 2>&1; rc=$? ;;
      0|1) taskset -c "$cores" "${one[@]}" > "$RUNS/$name.log" 2>&1; rc=$? ;;
      0,1)
        local multi=(--coordinator "localhost:$PORT" --num-processes 2)
        # process 1 in the background; process 0 (which writes) in the foreground
        taskset -c 1 "${one[@]}" "${multi[@]}" --process-id 1 > "$RUNS/$name.p1.log" 2>&1 &
        taskset -c 0 "${one[@]}" "${multi[@]}" --process-id 0 > "$RUNS/$name.log" 2>&1
        rc=$?; wait ;;
      *) popd > /dev/null; echo "piece: cores must be all, 0, 1 or 0,1 (got $cores)"; return 2 ;;
    esac
    popd > /dev/null || return 1
    [ "$rc" -eq 0 ] || { echo "FAILED $name (exit $rc; $RUNS/$name.log)"; return 1; }
  fi
  cp "$out/results.json" "results/$name.json" || { echo "FAILED $name (copying its results)"; return 1; }
  # a report that cannot read the new file must not hold back the next piece's training: say so, go on
  if flock "$RUNS/.land.lock" env PY="$PY" "$WT/results/queue/land.sh" > "$RUNS/$name.land.log" 2>&1; then
    echo "done $name $(date -u +%FT%TZ) (index and report regenerated; commit results BENCHMARKS.md docs/results figures)"
  else
    echo "done $name $(date -u +%FT%TZ), but regenerating the report FAILED ($RUNS/$name.land.log): fix, rerun land.sh"
  fi
}

pool() {  # pool SPEC...: the pieces, each SPEC "NAME ARG..." (split on spaces), on two workers each pinned to one
  # core (one process, XLA single-threaded: 1.5x one process of two threads, docs/speed.md), the next piece going
  # to whichever core frees first; PARALLEL=1: one after another on every core. Every piece is tried; returns 1
  # if any failed. For sweeps that cannot share one seed's policies between processes (priming reads BC-SO's).
  if [ "${PARALLEL:-2}" != 2 ]; then
    local spec words failed=0
    for spec in "$@"; do read -ra words <<< "$spec"; piece "${words[0]}" all "${words[@]:1}" || failed=1; done
    return "$failed"
  fi
  local next=$RUNS/.pool-next
  echo 0 > "$next"
  _pool_worker 1 "$next" "$@" & local other=$!
  _pool_worker 0 "$next" "$@"; local rc=$?
  wait "$other" || rc=1
  return "$rc"
}

_pool_worker() {  # _pool_worker CORE NEXT SPEC...: claims the next unclaimed SPEC (the index in file NEXT, under a
  # lock) and runs it pinned to CORE, until none is left
  local core=$1 next=$2; shift 2
  local specs=("$@") i words failed=0
  while :; do
    i=$( (flock 9; read -r i < "$next"; echo $((i + 1)) > "$next"; echo "$i") 9> "$next.lock")
    [ "$i" -lt "${#specs[@]}" ] || break
    read -ra words <<< "${specs[$i]}"
    piece "${words[0]}" "$core" "${words[@]:1}" || failed=1
  done
  return "$failed"
}
