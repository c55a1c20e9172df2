#!/usr/bin/env bash
# The exact commands that produced the checkpoints shipped in madp/checkpoints/ (see provenance.json there).
# Run from the repository root after `bash scripts/quickstart.sh` (or any install into .venv).
# Results do not depend on running the two trainings side by side or one after the other.
set -euo pipefail
DATA=${DATA:-/work/data100k}
[ -f "$DATA/manifest.json" ] || .venv/bin/madp datagen --n 100000 --seed 0 --out "$DATA" --workers 2   # ~30 min
# MADP: 24 x 1000 steps x 32 samples (768k samples, ~11 passes over the 70k training split), ~100 min on one thread.
.venv/bin/madp train --model madp --preset cpu --data "$DATA" --out runs/madp-cpu --threads 1 \
  --epochs 24 --max-steps-per-epoch 1000 &
# LPAC-K3: 6 x 1000 steps (192k samples), ~30 min on one thread.
.venv/bin/madp train --model lpac --preset cpu --data "$DATA" --out runs/lpac-cpu2 --threads 1 \
  --epochs 6 --max-steps-per-epoch 1000 &
wait
mkdir -p madp/checkpoints
cp runs/madp-cpu/checkpoints/best/policy.safetensors madp/checkpoints/madp-cpu.safetensors
cp runs/lpac-cpu2/checkpoints/best/policy.safetensors madp/checkpoints/lpac-cpu.safetensors
