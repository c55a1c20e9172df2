#!/usr/bin/env bash
# The exact commands that produced the checkpoints shipped in madp/checkpoints/ (see provenance.json there).
# Run from the repository root after `bash scripts/quickstart.sh` (or any install into .venv).
set -euo pipefail
DATA=${DATA:-/work/data100k}
.venv/bin/madp datagen --n 100000 --seed 0 --out "$DATA" --workers 2
# Both models train at the same time, one torch thread each (two cores).
.venv/bin/madp train --model madp --preset cpu --data "$DATA" --out runs/madp-cpu --threads 1 \
  --epochs "${MADP_EPOCHS:-6}" --max-steps-per-epoch "${STEPS_PER_EPOCH:-600}" &
.venv/bin/madp train --model lpac --preset cpu --data "$DATA" --out runs/lpac-cpu --threads 1 \
  --epochs "${LPAC_EPOCHS:-6}" --max-steps-per-epoch "${STEPS_PER_EPOCH:-600}" &
wait
mkdir -p madp/checkpoints
cp runs/madp-cpu/checkpoints/best/policy.safetensors madp/checkpoints/madp-cpu.safetensors
cp runs/lpac-cpu/checkpoints/best/policy.safetensors madp/checkpoints/lpac-cpu.safetensors
