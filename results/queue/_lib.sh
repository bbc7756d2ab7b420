# Shared by the queues (sourced): `sweep NAME ARGS...` runs one resumable sweep into $RUNS/NAME and copies its
# results to results/NAME.json; `judge_by NAME SIBLING` gives a file without a no-history control of its own the
# controlled verdict from SIBLING's BC-SO. Both expect WT (the checkout, the working directory), RUNS and PY.

sweep() {  # sweep NAME ARGS...: one sweep into $RUNS/NAME, its results to results/NAME.json
  local name=$1; shift
  if [ -f "results/$name.json" ]; then echo "skip $name (results/$name.json exists)"; return; fi
  if [ ! -f "$RUNS/$name/results.json" ]; then
    echo "start $name $(date -u +%FT%TZ)"
    # --resume where a sweep was started (a folder without one is refused with it), else a fresh start
    local resume=(); [ -f "$RUNS/$name/checkpoints/sweep.json" ] && resume=(--resume)
    "$PY" -m experiments.sweep "$@" --out "$RUNS/$name" "${resume[@]}" > "$RUNS/$name.log" 2>&1 \
      || { echo "FAILED $name (exit $?; $RUNS/$name.log)"; return; }
  fi
  cp "$RUNS/$name/results.json" "results/$name.json" && PY="$PY" "$WT/results/queue/land.sh" \
    && echo "done $name $(date -u +%FT%TZ)"
}

judge_by() {  # judge_by NAME SIBLING: results/NAME.json's controlled verdict from SIBLING's BC-SO, for a file with
  # none of its own (no BC-SO, or policies that see the previous action); idempotent, so rerun on every start
  [ -f "results/$1.json" ] || return
  "$PY" -m experiments.evaluate --rejudge "results/$1.json" --control "results/$2.json" > /dev/null \
    && echo "judged $1 against $2" || echo "FAILED judging $1 against $2"
}
