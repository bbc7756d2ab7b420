#!/usr/bin/env bash
# The prepared accelerator run (issue 18): the paper preset on Hopper `pos`, then as much of an
# image run as fits, with the measurements that go beside them. Run from the repository root:
#
#   experiments/device/fetch_wheels.sh               # here, once: the packages the GPU image lacks, into .whl/
#   experiments/device/run.sh                        # there (the device tool, carry [".whl"]): H200, ~8 min
#   experiments/device/run.sh --smoke                # here: tiny sizes on the CPU, to check the script
#   experiments/device/run.sh --plan paper-fca       # there: FCA (TCA and TCA+IB) at the paper's budget (issue 25)
#   experiments/device/run.sh --plan images          # there: MuJoCo-Image through the encoders, fine-tuned, ~9 min
#   experiments/device/run.sh --plan fcaexpert       # there: Table 5 with FCA's expert at the paper's 300k (issue 44)
#
# Plans: `default` (above); `paper-fca`: FCA and FCA-IB under `--preset paper --recipe fca` on Hopper (8 seeds)
# and HalfCheetah (3 seeds) side by side on the one card, each program's configurations as one block
# (`budget.width`), then the image encoders' training speed at 128x128 (ResNet-18 against the CPU default's
# patch encoder) in what is left. Collect their demonstrations here first, so the device trains on the
# same rows as this machine's runs (`.devdata/`, which the script makes `APE_JAX_CACHE` when it exists;
# carry it too):  APE_JAX_CACHE=.devdata python -m experiments.collect --env hopper --obs pos  (and halfcheetah)
# `images`: Hopper, Walker2d and HalfCheetah through each task's pretrained perception encoder (envs/perception/,
# 32x32), fine-tuned end to end (the paper's setting: recipe.perception_training=finetune) and frozen beside it in
# the same run at the same iterations; BC-SO, BC-OH, ours and FCA, 3 seeds, bfloat16, as many iterations as fit
# (`python -m experiments.device.images`, which says how it sizes them and refuses a plan that cannot fit), then
# the image encoders' speed (drq, patch, ResNet-18; float32 and bfloat16) in the last BENCH_S seconds (default 90).
# Its state demonstrations are collected here first (`--dry-run` prints the commands): APE_JAX_CACHE=.devdata
# python -m experiments.collect --env hopper --obs pos --protocol brax --episodes 100 (and walker2d, halfcheetah);
# the frames are rendered there. To fit the device tool's 64 MiB: experiments/device/fetch_wheels.sh --lean, then
# carry [".whl", ".devdata"] (55 MB); the encoders are tracked files and travel with the tree. --smoke: 783 s on
# the 2-core CPU beside two sweeps (2026-12-07).
# `fcaexpert`: Table 5 with FCA's own expert (raw labels) under `--preset paper --protocol mujoco-state --recipe bn-mlp`, Hopper,
# 8 seeds, one sweep per program side by side (BC-SO; BC-OH and ours; BC-full; FCA at alpha 0.1 and 2), each
# program's configurations as one block. Import the expert and collect its rows here first, into .devdata (the
# expert lives under .devdata/experts: git-ignored, it travels to the device and is never committed):
#   APE_JAX_CACHE=.devdata python -m experiments.import_expert PATH/TO/Hopper-v1.pkl --env hopper --name cs294
#   APE_JAX_CACHE=.devdata python -m experiments.collect --env hopper --obs pos --protocol mujoco-state \
#     --set protocol.expert=cs294 --set protocol.labels=raw
#
# Everything it keeps goes under $OUT (default: runs/device, or runs/device-smoke): measure.json
# (versions, devices, matmul peak, grid FLOP/s, MJX steps/s), nvidia-smi.txt, and per sweep its
# results.json, results.csv, log and wall time (timings.json). Sweeps write their checkpoints
# under $WORK (default /tmp/ape_device), not $OUT: those are large and need not travel back.
#
# The budget: BUDGET_S seconds in all (default 420, inside the 8 minutes of device time an issue
# sizes this run to, the machine's start apart; `images`: 540; --smoke: 1500, for a busy 2-core CPU); the paper
# sweep may use PAPER_S of them (default 300); the image run gets what is left, less 20 s for
# copying. A stage that runs out of time is stopped and says so.
set -uo pipefail
cd "$(dirname "$0")/../.."
SMOKE=0
PLAN=default
while [ $# -gt 0 ]; do
  case "$1" in
    --smoke) SMOKE=1 ;;
    --plan) PLAN=${2:-}; shift ;;
    -h|--help) sed -n '2,/^set -uo/{/^set -uo/!p;}' "$0"; exit 0 ;;
    *) echo "run.sh: error: unknown argument $1 (valid: --smoke, --plan default|paper-fca|images|fcaexpert)" >&2; exit 2 ;;
  esac
  shift
done
case "$PLAN" in
  default|paper-fca|images|fcaexpert) ;;
  *) echo "run.sh: error: unknown plan '$PLAN' (valid: default, paper-fca, images, fcaexpert)" >&2; exit 2 ;;
esac
START=$(date +%s)
if [ "$SMOKE" = 1 ]; then BUDGET_S=${BUDGET_S:-1500}
elif [ "$PLAN" = images ] || [ "$PLAN" = fcaexpert ]; then BUDGET_S=${BUDGET_S:-540}
else BUDGET_S=${BUDGET_S:-420}; fi
PAPER_S=${PAPER_S:-300}
if [ "$SMOKE" = 1 ]; then OUT=${OUT:-runs/device-smoke}; else OUT=${OUT:-runs/device}; fi
WORK=${WORK:-/tmp/ape_device}
mkdir -p "$OUT" "$WORK" || { echo "run.sh: error: cannot make $OUT or $WORK" >&2; exit 2; }
PY=${PYTHON:-python3}
export PYTHONUNBUFFERED=1
if [ -d .devdata ] && [ -z "${APE_JAX_CACHE:-}" ]; then export APE_JAX_CACHE=$PWD/.devdata; fi
# The device tool brings back at most 8 files: everything kept is also packed into $OUT/device.tgz after each stage.
pack() { local tmp="$WORK/device.$BASHPID.tgz"; tar -czf "$tmp" -C "$OUT" --exclude device.tgz . && mv "$tmp" "$OUT/device.tgz"; }

# 1. The carried wheels (experiments/device/fetch_wheels.sh put them in .whl/), then the repository.
PYVER=$($PY -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")') \
  || { echo "run.sh: error: no Python at $PY" >&2; exit 2; }
if ls .whl/*.whl >/dev/null 2>&1 && [ "$PYVER" != 3.12 ]; then
  echo "run.sh: .whl/ holds wheels for Python 3.12 (the GPU image's); $PY is $PYVER: using its own packages"
elif ls .whl/*.whl >/dev/null 2>&1; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || { echo "run.sh: error: installing the wheels in .whl/ failed" >&2; exit 1; }
  export PYTHONPATH=/tmp/site:$PWD${PYTHONPATH:+:$PYTHONPATH}
else
  export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
fi
if command -v nvidia-smi >/dev/null 2>&1; then nvidia-smi > "$OUT/nvidia-smi.txt" 2>&1; fi

left() { echo $(( BUDGET_S - ($(date +%s) - START) )); }

# stage NAME LIMIT_S ARGS...: one sweep under a time limit; keeps results and the log under $OUT/NAME.
stage() {
  local name=$1 limit=$2; shift 2
  if [ "$limit" -lt 10 ]; then echo "== $name: skipped (${limit} s of the budget left)"; return 0; fi
  echo "== $name: up to ${limit} s: python -m experiments.sweep $*"
  mkdir -p "$OUT/$name"
  local t0=$(date +%s)
  timeout --signal=INT --kill-after=15 "$limit" $PY -m experiments.sweep --quiet --out "$WORK/$name" "$@" \
    > "$OUT/$name/log.txt" 2>&1
  local rc=$? wall=$(( $(date +%s) - t0 ))
  tail -n 30 "$OUT/$name/log.txt"
  cp "$WORK/$name"/results.json "$WORK/$name"/results.csv "$OUT/$name/" 2>/dev/null
  local done=false; [ -f "$OUT/$name/results.json" ] && done=true
  printf '{"stage": "%s", "rc": %d, "wall_s": %d, "limit_s": %d, "finished": %s, "args": "%s"}\n' \
    "$name" "$rc" "$wall" "$limit" "$done" "$*" > "$OUT/$name/timings.json"
  pack
  if [ "$done" = true ]; then echo "== $name: finished in ${wall} s"
  else echo "== $name: stopped after ${wall} s (rc $rc) before it finished; its progress is in $OUT/$name/log.txt"; fi
}

# 2. The plan's stages. paper-fca: the two FCA sweeps, then the image encoders' speed; default: versions, the
#    device, the matmul peak, the grid's FLOP/s, MJX steps/s, then the paper sweeps.
if [ "$PLAN" = paper-fca ]; then
  # FCA's two variants share one program: 16 (Hopper) and 6 (HalfCheetah) configurations, each trained as one block.
  export XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.4}  # two processes share the card
  fca=(--obs pos --recipe bn-mlp --methods fca,fca-ib --step-grid 0.1:5)
  if [ "$SMOKE" = 1 ]; then fca+=(--smoke); else fca+=(--preset paper); fi
  stage hopper-pos-paper-fca "$(( $(left) - 60 ))" --env hopper "${fca[@]}" --seeds 8 --softmax-grid 0.2 \
    --set budget.width=16 &
  stage halfcheetah-pos-paper-fca "$(( $(left) - 60 ))" --env halfcheetah "${fca[@]}" --seeds 3 --softmax-grid 0.1 \
    --set budget.width=6 &
  wait
  bench=$(( $(left) - 20 ))
  if [ "$SMOKE" = 0 ] && [ "$bench" -gt 60 ]; then
    echo "== bench_images: up to ${bench} s"
    mkdir -p "$OUT/bench-images"
    timeout --signal=INT --kill-after=15 "$bench" $PY -m experiments.bench_images --sizes 128 \
      --encoders resnet18,patch+group --repeats 3 > "$OUT/bench-images/log.txt" 2>&1
    tail -n 30 "$OUT/bench-images/log.txt"
  fi
elif [ "$PLAN" = fcaexpert ]; then
  # Refused before anything compiles where the expert was not imported into the carried cache.
  [ -f "${APE_JAX_EXPERTS:-${APE_JAX_CACHE:-.devdata}/experts}/hopper-cs294/card.json" ] || {
    echo "run.sh: error: FCA's expert is not imported into ${APE_JAX_CACHE:-.devdata}/experts (see this script's header)" >&2
    exit 2; }
  # One process per program, side by side: on the GPU a small MLP's update is bound by launch latency, not by
  # its width, so the programs should overlap (unmeasured for four; paper-fca's two took 383 s and 328 s together,
  # 16 FCA models at 300k training in 219 s). A stage out of time stops and says so.
  export XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.2}
  common=(--env hopper --obs pos --protocol mujoco-state --recipe bn-mlp --seeds 8 --set protocol.expert=cs294
          --set protocol.labels=raw --step-grid 0.1:5 --softmax-grid 0.2 --set fca.alphas=0.1,2
          --set budget.width=24)
  # --smoke: enough episodes for the smoke's split whatever the expert (one that falls early too)
  if [ "$SMOKE" = 1 ]; then common+=(--smoke --set protocol.collect_transitions=2000); else common+=(--preset paper); fi
  name=hopper-pos-mujoco-state-rows-paper-bn-mlp-cs294-raw
  # The first sweep finds (or collects) the demonstrations before the others start, so no two collect them at once.
  stage "$name-bc-so" "$(( $(left) - 30 ))" "${common[@]}" --methods bc-so &
  first=$!
  until grep -q "^demonstrations: " "$OUT/$name-bc-so/log.txt" 2>/dev/null || ! kill -0 "$first" 2>/dev/null; do
    sleep 2
  done
  for methods in bc-oh,ours-step,ours-softmax bc-full fca; do
    stage "$name-${methods%%,*}" "$(( $(left) - 30 ))" "${common[@]}" --methods "$methods" &
  done
  wait
elif [ "$PLAN" = images ]; then
  # The grid, sized by experiments.device.images to what is left (less BENCH_S and 20 s for copying); it refuses
  # (exit 2, one line) a plan that cannot fit or whose demonstrations were not collected, before compiling.
  bench_s=${BENCH_S:-90}; [ "$SMOKE" = 1 ] && bench_s=0
  smoke=(); [ "$SMOKE" = 1 ] && smoke=(--smoke)
  $PY -m experiments.device.images --limit-s "$(( $(left) - bench_s - 20 ))" --out "$OUT/images" \
    --work "$WORK/images" "${smoke[@]}"
  rc=$?; pack
  [ "$rc" = 2 ] && exit 2
  bench=$(( $(left) - 20 ))
  if [ "$SMOKE" = 0 ] && [ "$bench" -gt 30 ]; then
    echo "== bench_images: up to ${bench} s"
    mkdir -p "$OUT/bench-images"
    timeout --signal=INT --kill-after=15 "$bench" $PY -m experiments.bench_images --sizes 84 --no-eval \
      --encoders drq@84,patch@64,resnet18@128 --dtype bfloat16,float32 --repeats 3 > "$OUT/bench-images/log.txt" 2>&1
    tail -n 30 "$OUT/bench-images/log.txt"
  fi
elif [ "$SMOKE" = 1 ]; then
  $PY -m experiments.device.measure --out "$OUT" --smoke --repeats 1 || exit $?
  stage hopper-pos-paper "$(( $(left) - 20 ))" --env hopper --obs pos --preset quick --iterations 20 --seeds 1 \
    --eval-episodes 1 --methods bc-so,bc-oh,ours-step --step-grid 0.1:5
  stage hopper-image-paper "$(( $(left) - 20 ))" --env hopper --obs image --preset quick --iterations 2 --seeds 1 \
    --eval-episodes 1 --methods bc-oh
else
  $PY -m experiments.device.measure --out "$OUT" || exit $?
  # 3. The paper preset on Hopper pos under the mujoco-state protocol: the default grid (14 configurations) x 5 seeds,
  #    300k iterations, 100 evaluation episodes.
  paper=$(left); [ "$paper" -gt "$PAPER_S" ] && paper=$PAPER_S
  stage hopper-pos-paper "$paper" --env hopper --obs pos --preset paper
  # 4. As much of the image protocol as fits: ResNet-18, batch 128, BC-OH and ours-step (10%, 5), one seed.
  stage hopper-image-paper "$(( $(left) - 20 ))" --env hopper --obs image --preset paper --seeds 1 \
    --methods bc-oh,ours-step --step-grid 0.1:5 --iterations "${IMAGE_ITERS:-20000}" --eval-episodes 10
fi
pack
echo "== run.sh: $(( $(date +%s) - START )) s in all; files under $OUT (and packed in $OUT/device.tgz)"
