#!/usr/bin/env bash
# The shipped MADP's sampler distilled into one step, on one GPU machine (docs/reports/2026-12-04-distillation.md):
#   states to learn on (expert rollouts on every core: uniform, narrow features, packed launches, 128-robot
#   swarms; the shipped policy's own rollouts at the evaluation default) -> madp train --distill on the GPU
#   (the student learns, from the same noise, the sample the teacher's DPM-Solver++(2M) draws in 3 steps)
#   -> OUT: the student's policy file, its metrics and config, the logs.
#
# Usage: bash scripts/gpu_distill.sh OUT [flags]
#   --python PY   interpreter that has madp's dependencies [python3]
#   --minutes M   training time budget [4]; the lr schedule is planned for --steps
#   --steps S     planned optimizer steps [4000]   --batch B   swarms per step [256]
#   --scale F     multiply every dataset's size by F (a small F checks the recipe on a CPU) [1]
#   --workers W   training loader workers [8]
# CUDA_TESTS_SECONDS=T in the environment: then run the cuda-marked tests for at most T seconds.
#   --work DIR    scratch: the datasets and the run [REPO/runs/distill]; new, empty, or an earlier
#                 scratch of this script (which it then removes)
# OUT (new or empty) receives at most 6 files: student.safetensors, metrics.jsonl, train-config.json,
# stages.tsv (stage, seconds, command), device.txt and logs.tar.gz (every stage's log).
set -euo pipefail

die() { echo "gpu_distill.sh: error: $*" >&2; exit 2; }
REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
[[ $# -ge 1 && $1 != -* ]] || die "usage: bash scripts/gpu_distill.sh OUT [--python PY] [--minutes M] [--steps S] [--batch B] [--scale F] [--workers W] [--work DIR]"
OUT=$1; shift
PY=python3 MINUTES=4 STEPS=4000 BATCH=256 SCALE=1 WORKERS=8 W=$REPO/runs/distill
while [[ $# -gt 0 ]]; do
  [[ $# -ge 2 ]] || die "$1 needs a value"
  case $1 in
    --python) PY=$2 ;; --minutes) MINUTES=$2 ;; --steps) STEPS=$2 ;; --batch) BATCH=$2 ;; --scale) SCALE=$2 ;; --workers) WORKERS=$2 ;;
    --work) W=$2 ;;
    *) die "unknown flag $1 (see the header of scripts/gpu_distill.sh)" ;;
  esac
  shift 2
done
[[ ! -e $OUT || -z $(ls -A "$OUT") ]] || die "$OUT is not empty"
[[ ! -e $W || -z $(ls -A "$W") || -e $W/.gpu_distill ]] || die "--work $W holds files this script did not write"
mkdir -p "$OUT/logs"; OUT=$(cd "$OUT" && pwd)
LOGS=$OUT/logs
pack() { tar -czf "$OUT/logs.tar.gz" -C "$OUT" logs && rm -rf "$LOGS"; }  # at most a few files come back
trap pack EXIT
cd "$REPO"
rm -rf "$W"; mkdir -p "$W"; touch "$W/.gpu_distill"
TEACHER=madp/checkpoints/madp-cpu.safetensors
madp() { "$PY" -m madp.cli "$@"; }
n() { "$PY" -c "print(max(64, int($1 * $SCALE)))"; }
stage() {  # stage NAME CMD...: run, log to OUT/NAME.log, record the wall time
  local name=$1; shift
  local t0=$SECONDS
  echo "== $name: $*"
  if ! "$@" > "$LOGS/$name.log" 2>&1; then tail -20 "$LOGS/$name.log"; die "stage $name failed (log: logs/$name.log)"; fi
  printf '%s\t%s\t%s\n' "$name" "$((SECONDS - t0))" "$*" >> "$OUT/stages.tsv"
  tail -2 "$LOGS/$name.log"
}

"$PY" - <<'EOF' | tee "$OUT/device.txt"
import os, torch
print("torch", torch.__version__, "cuda", torch.cuda.is_available(),
      torch.cuda.get_device_name(0) if torch.cuda.is_available() else "-", "cores", os.cpu_count())
EOF
rm -f "$OUT/stages.tsv"
# states (the labels are not used: the teacher's samples are the targets)
stage data-uniform madp datagen --n "$(n 40000)" --seed 2001 --out "$W"/uniform --workers 0
stage data-narrow madp datagen --n "$(n 10000)" --seed 2002 --sigma 5 40 --out "$W"/narrow --workers 0
stage data-packed madp datagen --n "$(n 10000)" --seed 2003 --launch packed --out "$W"/packed --workers 0
stage data-n128 madp datagen --n "$(n 3000)" --seed 2004 --num-robots 128 --out "$W"/n128 --workers 0
stage data-deployed madp datagen --n "$(n 6000)" --seed 2005 --policy $TEACHER --select explore --out "$W"/deployed --workers 0
per_epoch=$(( STEPS / 8 ))
stage train madp train --model madp --preset cpu --distill $TEACHER \
  --data "$W"/uniform --data "$W"/narrow --data "$W"/packed --data "$W"/n128 --data "$W"/deployed --data-weights 1,1,1,1,2 \
  --augment d4 --batch-size "$BATCH" --lr 3e-4 --workers "$WORKERS" --epochs 8 --max-steps-per-epoch "$per_epoch" \
  --stop-after-minutes "$MINUTES" --seed 2010 --out "$W"/student
cp "$W"/student/checkpoints/latest/policy.safetensors "$OUT/student.safetensors"
cp "$W"/student/metrics.jsonl "$OUT/metrics.jsonl"
cp "$W"/student/config.json "$OUT/train-config.json"
echo "student -> $OUT/student.safetensors"
if [[ -n ${CUDA_TESTS_SECONDS:-} ]]; then  # the cuda-marked tests, in the time left (their log is the point)
  timeout "$CUDA_TESTS_SECONDS" "$PY" -m pytest -q -p no:cacheprovider $(ls tests/*/test_cuda*.py) > "$LOGS/cuda-tests.log" 2>&1 || true
  tail -3 "$LOGS/cuda-tests.log"
fi
