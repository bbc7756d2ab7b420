#!/usr/bin/env bash
# MuJoCo-Image through each task's pretrained perception encoder (docs/perception.md; envs/perception/TASK.npz): the
# gate of issue "The paper's MuJoCo-Image experiment on a CPU", fixed before it ran (docs/design.md, "Perception
# gates"): image BC-SO through the encoder within 10 points (% of expert) of state BC-SO under the same protocol
# (`brax`: the committed from-scratch image tables'), recipe (`mlp`) and budget (the image `default` preset: 100
# demonstrations, 20,000 updates, 10 evaluation episodes, evaluated at 10,000 too), 3 seeds, per task.
# One piece after another on one core (the other runs the driving queue), lowest priority; rerun to go on.
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/mujoco-perceived}
PY=${PY:-$WT/.venv/bin/python}
CORE=${CORE:-1}
cd "$WT" || exit 2
mkdir -p "$RUNS/exploratory"
source "$WT/results/queue/_lib.sh"
budget=(--preset default --seeds 3 --methods bc-so --quiet)
# Why HalfCheetah misses the gate (DIAG_ONLY=1): the state policy fed the encoder's error, i.e. BC-SO on the
# encoder's read-out of `pos` (its estimate of the one-frame state, in its units: recipe.perception_output=readout)
# at the gate's settings, beside the state BC-SO (exploratory/halfcheetah-pos-brax-gate) and the embedding's
# ENC64=PATH: then the gate at 64x64 through the encoder pretrained on 64x64 frames (`python -m experiments.perception
# --env halfcheetah --image-size 64 --out results/exploratory/perception/halfcheetah-64.json --encoder PATH`)
if [ "${DIAG_ONLY:-0}" = 1 ]; then
  piece exploratory/halfcheetah-image-perceived-readout-gate "$CORE" --env halfcheetah --obs image "${budget[@]}" \
    --set recipe.perception=task --set recipe.perception_output=readout || exit 1
  if [ -n "${ENC64:-}" ]; then
    piece exploratory/halfcheetah-image-64-perceived-gate "$CORE" --env halfcheetah --obs image "${budget[@]}" \
      --set "recipe.perception=$ENC64" --set protocol.image_size=64 || exit 1
  fi
  exit 0
fi
failed=0
for task in hopper walker2d halfcheetah; do
  piece "exploratory/$task-image-perceived-gate" "$CORE" --env "$task" --obs image "${budget[@]}" \
    --set recipe.perception=task || failed=1
  piece "exploratory/$task-pos-brax-gate" "$CORE" --env "$task" --obs pos --protocol brax "${budget[@]}" \
    --set budget.iterations=20000 --set budget.eval_episodes=10 --set budget.eval_at=10000 \
    --set protocol.episodes=100 --set budget.chunk=1000 || failed=1
done
exit "$failed"
