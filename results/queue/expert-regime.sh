#!/usr/bin/env bash
# The expert-regime sweeps (issue 44): Table 5 with FCA's own expert, the rough experts' tables and the previous
# action in view. Run from a checkout (WT, default: this script's repository) with the FCA expert imported once:
#   python -m experiments.import_expert PATH/TO/fighting-copycat-agents/data/experts/Hopper-v1.pkl --env hopper --name fca
# Each sweep resumes where it stopped (--resume) and is skipped once its results file exists; RUNS holds the run
# folders (checkpoints, policies). A finished sweep's results.json is copied to results/NAME.json, to be committed.
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/t5}
PY=${PY:-$WT/.venv/bin/python}
cd "$WT" || exit 2
mkdir -p "$RUNS"
TABLE5="--protocol fca --recipe fca --preset default --methods bc-so,bc-oh,bc-full,ours-step,ours-softmax,fca
        --set recipe.step_grid=0.1:5 --set recipe.softmax_grid=0.2"

sweep() {  # sweep NAME ARGS...: one sweep into $RUNS/NAME, its results to results/NAME.json
  local name=$1; shift
  if [ -f "results/$name.json" ]; then echo "skip $name (results/$name.json exists)"; return; fi
  echo "start $name $(date -u +%FT%TZ)"
  if "$PY" -m experiments.sweep "$@" --out "$RUNS/$name" --resume > "$RUNS/$name.log" 2>&1; then
    cp "$RUNS/$name/results.json" "results/$name.json" && echo "done $name $(date -u +%FT%TZ)"
  else
    echo "FAILED $name (exit $?; $RUNS/$name.log)"
  fi
}

# Table 5 with FCA's expert (Hopper): raw labels as FCA stored them, and clipped; FCA at the supplement's alpha 0.1
# and FCA's code's 2.0; 8 seeds
sweep hopper-pos-fca-rows-default-fca-fcaexpert-raw --env hopper $TABLE5 --seeds 8 \
  --set protocol.expert=fca --set protocol.labels=raw --set recipe.fca_alphas=0.1,2
sweep hopper-pos-fca-rows-default-fca-fcaexpert-clipped --env hopper $TABLE5 --seeds 8 \
  --set protocol.expert=fca --set recipe.fca_alphas=0.1,2
# The rough shipped experts (raw labels), 5 seeds; FCA at the supplement's alpha (Hopper 0.1, the others 0.5) and
# FCA's code's (Hopper 2.0, the others 1.0)
for env in hopper walker2d halfcheetah; do
  [ -f "envs/experts/$env-rough/card.json" ] || { echo "skip $env-rough (no shipped expert yet)"; continue; }
  alphas=$([ "$env" = hopper ] && echo 0.1,2 || echo 0.5,1)
  sweep $env-pos-fca-rows-default-fca-rough-raw --env $env $TABLE5 --seeds 5 \
    --set protocol.expert=rough --set protocol.labels=raw --set recipe.fca_alphas=$alphas
done
# The previous action in view (Hopper, the shipped SAC expert): one more row of the copycat map; 5 seeds
sweep hopper-pos-fca-rows-default-fca-prevaction --env hopper --protocol fca --recipe fca --preset default --seeds 5 \
  --methods bc-so,bc-oh,bc-full,ours-step --set recipe.step_grid=0.1:5 --set protocol.prev_action=true
