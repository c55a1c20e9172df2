#!/usr/bin/env bash
# The paper's model on one fresh GPU machine (defaults sized for one H200 with 16 cores: ~8 min, estimated):
#   install -> preflight (torch, the device, the numba kernels) -> the `cuda`-marked tests -> madp datagen --n 100000 (all cores)
#   -> madp train --preset paper (bf16 autocast on the GPU, a time budget) [-> one DAgger round]
#   -> the checkpoint in float16, split into parts of at most 16 MiB -> madp eval uniform,cities with
#   MADP decentralized on the GPU -> madp bench infer (latency on the GPU) -> RESULTS_DIR.
#
# Usage: bash scripts/gpu_paper.sh RESULTS_DIR [flags]      (run from anywhere; docs/guides/gpu.md)
#
# RESULTS_DIR (new or empty) receives at most --max-files files of at most --max-file-mib MiB each:
#   provenance.json                      commit, date, device, torch/CUDA, every command with its stage time,
#                                        the headline figures, and the size and sha256 of every other file
#   outputs.tar.gz                       train metrics.jsonl + config.json, eval summary.json/md, config.json,
#                                        results.parquet and plot per suite, bench-infer.json, the cuda test
#                                        log, the dataset manifest(s), every stage's log, stages.tsv
#   policy-fp16.safetensors[.parts.json, .000, .001, ...]
#                                        the trained policy in float16 (split when larger than --part-mib);
#                                        `madp eval --madp RESULTS_DIR/policy-fp16.safetensors.parts.json`
#                                        (or the first part) loads it on CPU or GPU, joined and checked
# Scratch (dataset, runs) goes to --work (default runs/gpu-paper under the repository).
#
# Flags (defaults in brackets):
#   --python PY          use this interpreter as it is: no install [create WORK/venv, see --wheels]
#   --wheels DIR         install offline from these wheels (pip --no-index --find-links DIR)
#   --work DIR           scratch directory [REPO/runs/gpu-paper]
#   --device DEV         where eval and bench run MADP: auto | cuda | cpu [auto: cuda when torch sees one]
#   --n N                samples of expert data [100000]        --datagen-workers W   [0: all cores]
#   --datagen-args STR   more `madp datagen` flags, e.g. "--world-size 256 --num-robots 4" [none]
#   --preset P           paper | cpu [paper]                    --batch-size B        [the preset's]
#   --train-minutes M    training time budget [3]               --train-steps S       [0: no cap]
#   --train-workers W    DataLoader workers [8]                 --train-args STR      more `madp train` flags
#   --dagger-n N         one DAgger round on N relabelled samples (0: none) [0]
#   --dagger-minutes M   its training budget [2]
#   --eval-suites LIST   [uniform,cities]                       --eval-controllers L  [clairvoyant,dcvt,madp]
#   --eval-envs N        environments per suite [50]            --eval-steps T        [600]
#   --eval-workers W     [0: all cores]
#   --bench-presets L    [cpu,paper]   --bench-grid G ["dpm++:3;ddim:10"; DDIM-50 always]   --bench-repeats R [5]
#   --no-cuda-tests      skip the `cuda`-marked tests
#   --part-mib M         largest checkpoint part [16]   --max-files N [8]   --max-file-mib M [16]
#
# Every stage logs its command and wall time; a failing stage stops the run with a line naming it and its
# log, and what was made so far (logs included) is still packed into RESULTS_DIR. Failing `cuda` tests do
# not stop the run (their log is the point); the script then exits 1 after packing.
set -euo pipefail

die() { echo "gpu_paper.sh: error: $*" >&2; exit 2; }
REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)

[[ $# -ge 1 && $1 != -* ]] || die "usage: bash scripts/gpu_paper.sh RESULTS_DIR [flags] (see the header of this script)"
RESULTS=$1; shift
PY="" WHEELS="" WORK="$REPO/runs/gpu-paper" DEVICE=auto
N=100000 DATAGEN_WORKERS=0 DATAGEN_ARGS=""
PRESET=paper BATCH="" TRAIN_MINUTES=3 TRAIN_STEPS=0 TRAIN_WORKERS=8 TRAIN_ARGS=""
DAGGER_N=0 DAGGER_MINUTES=2
EVAL_SUITES=uniform,cities EVAL_CONTROLLERS=clairvoyant,dcvt,madp EVAL_ENVS=50 EVAL_STEPS=600 EVAL_WORKERS=0
BENCH_PRESETS=cpu,paper BENCH_GRID="dpm++:3;ddim:10" BENCH_REPEATS=5
CUDA_TESTS=1 PART_MIB=16 MAX_FILES=8 MAX_FILE_MIB=16
ARGS=("$@")
while [[ $# -gt 0 ]]; do
  flag=$1
  case $flag in
    --no-cuda-tests) CUDA_TESTS=0; shift; continue ;;
    --python|--wheels|--work|--device|--n|--datagen-workers|--datagen-args|--preset|--batch-size|--train-minutes|\
    --train-steps|--train-workers|--train-args|--dagger-n|--dagger-minutes|--eval-suites|--eval-controllers|\
    --eval-envs|--eval-steps|--eval-workers|--bench-presets|--bench-grid|--bench-repeats|--part-mib|--max-files|\
    --max-file-mib) [[ $# -ge 2 ]] || die "$flag: needs a value" ;;
    *) die "unknown flag $flag (see the header of scripts/gpu_paper.sh)" ;;
  esac
  v=$2; shift 2
  case $flag in
    --python) PY=$v ;; --wheels) WHEELS=$v ;; --work) WORK=$v ;; --device) DEVICE=$v ;;
    --n) N=$v ;; --datagen-workers) DATAGEN_WORKERS=$v ;; --datagen-args) DATAGEN_ARGS=$v ;;
    --preset) PRESET=$v ;; --batch-size) BATCH=$v ;; --train-minutes) TRAIN_MINUTES=$v ;;
    --train-steps) TRAIN_STEPS=$v ;; --train-workers) TRAIN_WORKERS=$v ;; --train-args) TRAIN_ARGS=$v ;;
    --dagger-n) DAGGER_N=$v ;; --dagger-minutes) DAGGER_MINUTES=$v ;;
    --eval-suites) EVAL_SUITES=$v ;; --eval-controllers) EVAL_CONTROLLERS=$v ;; --eval-envs) EVAL_ENVS=$v ;;
    --eval-steps) EVAL_STEPS=$v ;; --eval-workers) EVAL_WORKERS=$v ;;
    --bench-presets) BENCH_PRESETS=$v ;; --bench-grid) BENCH_GRID=$v ;; --bench-repeats) BENCH_REPEATS=$v ;;
    --part-mib) PART_MIB=$v ;; --max-files) MAX_FILES=$v ;; --max-file-mib) MAX_FILE_MIB=$v ;;
  esac
done
for v in N DATAGEN_WORKERS TRAIN_STEPS TRAIN_WORKERS DAGGER_N EVAL_ENVS EVAL_STEPS EVAL_WORKERS BENCH_REPEATS MAX_FILES MAX_FILE_MIB; do
  [[ ${!v} =~ ^[0-9]+$ ]] || die "--$(echo "$v" | tr 'A-Z_' 'a-z-'): expected a non-negative integer, got '${!v}'"
done
for v in TRAIN_MINUTES DAGGER_MINUTES PART_MIB; do
  [[ ${!v} =~ ^[0-9]+([.][0-9]+)?$ ]] || die "--$(echo "$v" | tr 'A-Z_' 'a-z-'): expected a non-negative number, got '${!v}'"
done
[[ -z $BATCH || $BATCH =~ ^[1-9][0-9]*$ ]] || die "--batch-size: expected a positive integer, got '$BATCH'"
[[ $TRAIN_MINUTES != 0 || $TRAIN_STEPS != 0 ]] || die "--train-minutes 0 needs --train-steps S > 0 (a budget)"
[[ $DAGGER_N == 0 || $DAGGER_MINUTES != 0 || $TRAIN_STEPS != 0 ]] || die "--dagger-minutes 0 needs --train-steps S > 0 (a budget)"
if [[ $PY == */* ]]; then PY=$(cd "$(dirname "$PY")" && pwd)/$(basename "$PY") || die "--python $PY: not found"; fi
if [[ -e $RESULTS && -n $(ls -A "$RESULTS" 2>/dev/null) ]]; then die "$RESULTS: not empty; choose a new RESULTS_DIR"; fi
[[ ! -e $WORK/train ]] || die "$WORK/train: a training run is already there; remove it or pass another --work"
mkdir -p "$RESULTS" "$WORK/logs"
RESULTS=$(cd "$RESULTS" && pwd); WORK=$(cd "$WORK" && pwd)
LOGS=$WORK/logs STAGES=$WORK/logs/stages.tsv
: >"$STAGES"
export PYTHONPATH="$REPO${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
T0=$SECONDS
CUDA_TESTS_RC=0 FAILED=""

# stage NAME CMD...: run CMD, its output to the console and LOGS/NAME.log; record NAME, seconds, exit status
# and the command in stages.tsv; a failure packs what exists and stops the script.
stage() {
  local name=$1; shift
  local t=$SECONDS rc
  echo "== $name ($(date -u +%H:%M:%S) UTC, +$((SECONDS - T0)) s): $*"
  set +e
  "$@" 2>&1 | tee "$LOGS/$name.log"
  rc=${PIPESTATUS[0]}
  set -e
  local cmd="$*"
  cmd=${cmd//$'\n'/ }
  printf '%s\t%d\t%d\t%s\n' "$name" $((SECONDS - t)) "$rc" "${cmd//$'\t'/ }" >>"$STAGES"
  echo "== $name: exit $rc after $((SECONDS - t)) s"
  if [[ $rc -ne 0 && $name != cuda-tests ]]; then
    FAILED=$name
    echo "gpu_paper.sh: stage '$name' failed (exit $rc); its log: $LOGS/$name.log; packing what exists into $RESULTS" >&2
    pack || true
    exit 1
  fi
  [[ $name != cuda-tests ]] || CUDA_TESTS_RC=$rc
}
madp() { "$PY" -m madp.cli "$@"; }

# pack: the small outputs into one archive, provenance.json beside it; then check the limits on what comes back.
pack() {
  local stage_dir=$WORK/pack
  rm -rf "$stage_dir" "$RESULTS/outputs.tar.gz"
  mkdir -p "$stage_dir/logs"
  cp "$LOGS"/* "$stage_dir/logs/"
  for run in train train-dagger; do
    if [[ -d $WORK/$run ]]; then
      mkdir -p "$stage_dir/$run"
      cp "$WORK/$run"/metrics.jsonl "$WORK/$run"/config.json "$stage_dir/$run/" 2>/dev/null || true
    fi
  done
  for d in data dagger; do
    if [[ -f $WORK/$d/manifest.json ]]; then mkdir -p "$stage_dir/$d"; cp "$WORK/$d/manifest.json" "$stage_dir/$d/"; fi
  done
  local s
  for s in ${EVAL_SUITES//,/ }; do
    if [[ -d $WORK/eval/$s ]]; then
      mkdir -p "$stage_dir/eval/$s"
      (cd "$WORK/eval/$s" && cp -- summary.json summary.md config.json results.parquet *.png "$stage_dir/eval/$s/" 2>/dev/null) || true
    fi
  done
  [[ ! -f $WORK/bench-infer.json ]] || cp "$WORK/bench-infer.json" "$stage_dir/"
  tar -czf "$RESULTS/outputs.tar.gz" -C "$stage_dir" .
  "${PY:-python3}" - "$RESULTS" "$STAGES" "$REPO" "$DEVICE" "$FAILED" "$CUDA_TESTS_RC" "$MAX_FILES" "$MAX_FILE_MIB" \
      "$WORK" "$EVAL_SUITES" "${ARGS[@]+"${ARGS[@]}"}" <<'PYEOF'
import hashlib, json, platform, subprocess, sys, time
from pathlib import Path

results, stages, repo, device, failed, cuda_rc, max_files, max_mib, work, suites, *args = sys.argv[1:]
results, work = Path(results), Path(work)


def git(*a):
    try:
        return subprocess.run(["git", "-C", repo, *a], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


try:
    import torch
    dev = {"torch": torch.__version__, "cuda": torch.version.cuda,
           "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None}
except ImportError:
    dev = {"torch": None, "cuda": None, "gpu": None}
figures = {}
for s in filter(None, suites.split(",")):
    f = work / "eval" / s / "summary.json"
    if f.is_file():
        doc = json.loads(f.read_text())
        figures[s] = {c: {k: v[k] for k in ("n", "mean", "se", "mean_step_ms") if k in v} for c, v in doc["overall"].items()}
bench = work / "bench-infer.json"
latency = None
if bench.is_file():
    latency = [{k: x[k] for k in ("preset", "mode", "sampler", "num_steps", "latency_s", "device")}
               for x in json.loads(bench.read_text())["latency"]]
rows = [ln.split("\t", 3) for ln in Path(stages).read_text().splitlines() if ln]
files = {p.name: {"bytes": p.stat().st_size, "sha256": hashlib.sha256(p.read_bytes()).hexdigest()}
         for p in sorted(results.iterdir()) if p.is_file() and p.name != "provenance.json"}
doc = {"script": "scripts/gpu_paper.sh", "args": args, "commit": git("rev-parse", "HEAD"),
       "dirty": bool(git("status", "--porcelain", "--untracked-files=no")) if git("rev-parse", "HEAD") else None,
       "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "host": platform.node(),
       "python": platform.python_version(), "eval_device": device, **dev,
       "stages": [{"name": n, "seconds": int(t), "exit": int(rc), "command": c} for n, t, rc, c in rows],
       "failed_stage": failed or None, "cuda_tests_exit": int(cuda_rc), "figures": figures, "latency": latency,
       "files": files}
(results / "provenance.json").write_text(json.dumps(doc, indent=1) + "\n")
out = sorted(p for p in results.iterdir())
big = [f"{p.name} ({p.stat().st_size / 2**20:.1f} MiB)" for p in out if p.stat().st_size > int(max_mib) * 2**20]
if len(out) > int(max_files) or big or any(not p.is_file() for p in out):
    sys.exit(f"gpu_paper.sh: error: {results} holds {len(out)} entries (at most {max_files} files of at most "
             f"{max_mib} MiB may come back){'; too large: ' + ', '.join(big) if big else ''}")
PYEOF
}

# --- 1. install (unless --python) -----------------------------------------------------------------------
if [[ -z $PY ]]; then
  pipflags=(-q)
  [[ -z $WHEELS ]] || pipflags+=(--no-index --find-links "$WHEELS" --no-build-isolation)
  # --system-site-packages: the machine's CUDA torch (and whatever else it has) is used, not replaced
  stage install bash -c 'python3 -m venv --system-site-packages "$1" && "$1/bin/pip" install "${@:3}" -e "$2"' \
    _ "$WORK/venv" "$REPO" "${pipflags[@]}"
  PY=$WORK/venv/bin/python
fi
command -v "$PY" >/dev/null || die "--python $PY: not found"
echo "gpu_paper.sh: python $PY, work $WORK, results $RESULTS"

# --- 2. preflight: the interpreter, torch, the device; the numba kernels compiled once, before every worker would --
stage preflight "$PY" -c '
import runpy, sys
import torch
from madp.policies.device import resolve_device
print(f"python {sys.version.split()[0]}, torch {torch.__version__}, CUDA {torch.version.cuda}, "
      f"GPU: {torch.cuda.get_device_name(0) if torch.cuda.is_available() else None}")
print(f"--device {sys.argv[1]} -> {resolve_device(sys.argv[1])}")
runpy.run_path(sys.argv[2], run_name="__main__")' "$DEVICE" "$REPO/scripts/warm_kernels.py"

# --- 3. the cuda-marked tests (skipped without a GPU) ------------------------------------------------------
if [[ $CUDA_TESTS == 1 ]]; then
  mapfile -t cuda_files < <(cd "$REPO" && find tests -name 'test_cuda*.py' | sort)
  [[ ${#cuda_files[@]} -gt 0 ]] || die "no tests/**/test_cuda*.py found in $REPO"
  stage cuda-tests bash -c 'cd "$1" && shift && "$0" -m pytest -q -rs -m cuda -p no:cacheprovider "$@"' "$PY" "$REPO" "${cuda_files[@]}"
fi

# --- 4. expert data ---------------------------------------------------------------------------------------
# shellcheck disable=SC2086  # the *_ARGS strings are word-split on purpose
stage datagen madp datagen --n "$N" --out "$WORK/data" --workers "$DATAGEN_WORKERS" $DATAGEN_ARGS

# --- 5. training (bf16 autocast on the GPU: madp.training.trainer) ----------------------------------------
budget=()
[[ $TRAIN_MINUTES == 0 ]] || budget+=(--stop-after-minutes "$TRAIN_MINUTES")
[[ $TRAIN_STEPS == 0 ]] || budget+=(--stop-after-steps "$TRAIN_STEPS")
[[ -z $BATCH ]] || budget+=(--batch-size "$BATCH")
# shellcheck disable=SC2086
stage train madp train --model madp --preset "$PRESET" --data "$WORK/data" --out "$WORK/train" \
  --workers "$TRAIN_WORKERS" "${budget[@]}" $TRAIN_ARGS
CKPT=$WORK/train/checkpoints/latest/policy.safetensors

# --- 6. one DAgger round (optional): the policy drives, the expert labels, warm start on both sets ----------
if [[ $DAGGER_N != 0 ]]; then
  # shellcheck disable=SC2086
  stage dagger-datagen madp datagen --n "$DAGGER_N" --seed 1 --policy "$CKPT" --out "$WORK/dagger" \
    --workers "$DATAGEN_WORKERS" $DATAGEN_ARGS
  dbudget=()
  [[ $DAGGER_MINUTES == 0 ]] || dbudget+=(--stop-after-minutes "$DAGGER_MINUTES")
  [[ $TRAIN_STEPS == 0 ]] || dbudget+=(--stop-after-steps "$TRAIN_STEPS")
  [[ -z $BATCH ]] || dbudget+=(--batch-size "$BATCH")
  # shellcheck disable=SC2086
  stage dagger-train madp train --model madp --preset "$PRESET" --data "$WORK/data" --data "$WORK/dagger" \
    --data-weights 1,4 --init "$CKPT" --out "$WORK/train-dagger" --workers "$TRAIN_WORKERS" "${dbudget[@]}" $TRAIN_ARGS
  CKPT=$WORK/train-dagger/checkpoints/latest/policy.safetensors
fi

# --- 7. the shipped form: float16, split into parts of at most --part-mib -------------------------------------
stage fp16 "$PY" -m madp.policies.fp16 "$CKPT" "$RESULTS/policy-fp16.safetensors" --part-mib "$PART_MIB"
SHIPPED=$RESULTS/policy-fp16.safetensors
[[ -f $SHIPPED ]] || SHIPPED=$RESULTS/policy-fp16.safetensors.parts.json

# --- 8. evaluation of the shipped form, MADP decentralized on the device ------------------------------------
stage eval madp eval --suite "$EVAL_SUITES" --controllers "$EVAL_CONTROLLERS" --madp "$SHIPPED" --device "$DEVICE" \
  --num-envs "$EVAL_ENVS" --steps "$EVAL_STEPS" --workers "$EVAL_WORKERS" --out "$WORK/eval"

# --- 9. latency per control step on the device (random weights of each preset: latency does not depend on them) --
stage bench madp bench infer --no-sweep --device "$DEVICE" --presets "$BENCH_PRESETS" --grid "$BENCH_GRID" \
  --repeats "$BENCH_REPEATS" --no-robot --out "$WORK/bench-infer.json"  # the robot runtime is a CPU figure: madp bench infer on the CPU

# --- 10. pack -----------------------------------------------------------------------------------------------
pack
echo "== stages:"; awk -F'\t' '{printf "   %-15s %5d s  exit %d\n", $1, $2, $3}' "$STAGES"
ls -l "$RESULTS"
echo "gpu_paper.sh: done in $((SECONDS - T0)) s -> $RESULTS"
if [[ $CUDA_TESTS_RC -ne 0 ]]; then
  echo "gpu_paper.sh: the cuda-marked tests failed (exit $CUDA_TESTS_RC); see logs/cuda-tests.log in outputs.tar.gz" >&2
  exit 1
fi
