#!/usr/bin/env bash
# Issue 25: the first recipe's whole-episode fca files trained again with today's code, so their policies
# (and copycat diagnostics) exist. One sweep at a time; --resume makes the queue restartable. Run on the 2-core
# AMD EPYC from worktrees of this repository, each sweep's output in /work/runs/r25/NAME (not kept by git);
# results/retrained/README.md says how each is then written over the file it replaces. Hopper's ran from
# /work/wt_r25 at 016f0b2 (its FCA from /work/wt_r25b at 1ee6ab4, which has recipe.fca_adversary_lr);
# Walker2d's and HalfCheetah's from /work/wt_r25c at 6afdeb3, which records the demonstrations' SHA-256 (when the
# machine lost /work/runs and the cache, the worktree was made again at 6afdeb3 and the queue restarted from
# walker2d-grid; the runs after it take the order below).
cd /work/wt_r25c
PY=/work/main/.venv/bin/python
COMMON="--quiet --preset default --resume --recipe mlp --set protocol.split=episodes"
run() {  # name protocol env args...
  name=$1; proto=$2; env=$3; shift 3
  if [ -f /work/runs/r25/$name/results.json ] && grep -q '"status"' /work/runs/r25/$name/results.json && [ -f /work/runs/r25/$name.done ]; then return; fi
  s=$(date +%s)
  (cd ${WT:-/work/wt_r25c} && $PY -m experiments.sweep $COMMON --out /work/runs/r25/$name --env $env --protocol $proto "$@" > /work/runs/r25/$name.log 2>&1)
  rc=$?
  echo "$name: exit $rc, $(( $(date +%s) - s )) s, $(date)" >> /work/runs/r25/queue.log
  [ $rc -eq 0 ] && touch /work/runs/r25/$name.done
}
run hopper-main fca hopper --methods bc-so,bc-oh,ours-step --step-grid 0.1:5 --seeds 5
run hopper-softmax fca hopper --methods ours-softmax --seeds 5
run hopper-baselines fca hopper --methods history-dropout,bcpd,actfreq,boosting,kmeans,dagger --seeds 5
run hopper-grid fca hopper --methods ours-step --step-grid 0.1:3,0.1:10,0.2:3,0.2:5,0.2:10 --seeds 5
WT=/work/wt_r25b run hopper-fca fca hopper --methods fca --seeds 5 --set recipe.fca_alphas=0.1 --set recipe.fca_adversary_lr=0.0002
for p in fca-fs2 fca-fs4 fca-train5k fca-train80k; do
  run hopper-$p-map $p hopper --methods bc-so,bc-oh,ours-step --step-grid 0.1:5 --seeds 3
done
run hopper-long fca hopper --methods bc-oh,ours-step --step-grid 0.1:5 --seeds 2 --iterations 100000 --checkpoint-every 10000
run walker2d-main fca walker2d --methods bc-so,bc-oh,ours-step --step-grid 0.1:5 --seeds 5
run walker2d-softmax fca walker2d --methods ours-softmax,fca --seeds 5 --set recipe.fca_alphas=0.5
run walker2d-baselines fca walker2d --methods history-dropout,bcpd,actfreq,boosting,kmeans,dagger --seeds 3
run walker2d-grid fca walker2d --methods ours-step --step-grid 0.1:3,0.1:10,0.2:3,0.2:5,0.2:10 --seeds 5
run halfcheetah-main fca halfcheetah --methods bc-so,bc-oh,ours-step --step-grid 0.1:5 --seeds 5
run halfcheetah-baselines fca halfcheetah --methods history-dropout,bcpd,actfreq,boosting,kmeans,dagger --seeds 3
run halfcheetah-softmax fca halfcheetah --methods ours-softmax,fca --seeds 5 --set recipe.fca_alphas=0.5
run halfcheetah-grid fca halfcheetah --methods ours-step --step-grid 0.1:3,0.1:10,0.2:3,0.2:5,0.2:10 --seeds 5
echo "queue finished $(date)" >> /work/runs/r25/queue.log
