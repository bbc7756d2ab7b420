#!/usr/bin/env bash
# The MuJoCo-Image table through each task's pretrained perception encoder (issue "The paper's MuJoCo-Image
# experiment on a CPU"; docs/perception.md; envs/perception/TASK.npz, cards in results/perception/): Hopper, Walker2d
# and HalfCheetah, the `brax` image protocol and the image `default` budget of the committed from-scratch image files
# (TASK-image-patch-*.json, the "no pretraining" rows): 100 demonstrations, 20,000 updates, 10 evaluation episodes;
# not evaluated at 10,000 too (budget.eval_at empty: every rollout step renders and embeds a frame, and the midway
# evaluation would cost a quarter of the table). 5 seeds. Methods: BC-SO, BC-OH, ours (step THR 10% W 5; softmax at
# the paper's tau: 0.2 for Hopper and Walker2d, 0.1 for HalfCheetah), FCA and PALR at the preset's settings, BC-full.
# Two pieces per task (SUFFIX bc: BC-SO, BC-OH, ours; baselines: FCA, PALR, BC-full), two at a time, each pinned to
# one core, lowest priority. Rerun to go on: a landed piece is skipped, a started one resumes from its checkpoints.
set -uo pipefail
WT=${WT:-$(cd "$(dirname "$0")/../.." && pwd)}
RUNS=${RUNS:-/work/runs/mujoco-perceived-table}
PY=${PY:-$WT/.venv/bin/python}
cd "$WT" || exit 2
mkdir -p "$RUNS"
source "$WT/results/queue/_lib.sh"
specs=()
for task in ${TASKS:-hopper walker2d halfcheetah}; do
  tau=0.2; [ "$task" = halfcheetah ] && tau=0.1
  common="--env $task --obs image --preset default --seeds 5 --quiet --set recipe.perception=task --set budget.eval_at="
  specs+=("$task-image-default-perceived-bc $common --methods bc-so,bc-oh,ours-step,ours-softmax --set ours-step.grid=0.1:5 --set ours-softmax.taus=$tau")
  specs+=("$task-image-default-perceived-baselines $common --methods fca,palr,bc-full")
done
pool "${specs[@]}"
status=$?
# the baselines pieces have no BC-SO of their own: their controlled verdict is judged against their task's bc piece
for task in ${TASKS:-hopper walker2d halfcheetah}; do
  judge_by "$task-image-default-perceived-baselines" "$task-image-default-perceived-bc"
done
exit "$status"
