#!/usr/bin/env bash
# The exact commands that produced the checkpoints shipped in madp/checkpoints/ (record: provenance.json there).
# Run from the repository root after `bash scripts/quickstart.sh` (or any install into .venv).
# Round 0 trains on the expert data; scripts/train_dagger.sh then runs the expert-relabelling rounds
# (MADP: 2, LPAC-K3: 1), scripts/train_rounds_3to5.sh MADP's rounds 3-5 (narrow features, 128-robot
# swarms) and scripts/train_rounds_6to8.sh rounds 6-8 (packed starts with d4 augmentation, then narrow
# features and 128-robot swarms back in the mix); the last round of each is shipped.
# About 9 h on 2 cores end to end.
# Results do not depend on running the two trainings side by side or one after the other.
set -euo pipefail
DATA=${DATA:-data/expert-100k}   # the expert dataset (and, beside it, the relabelled sets); DATA=PATH puts them elsewhere
[ -f "$DATA/manifest.json" ] || .venv/bin/madp datagen --n 100000 --seed 0 --out "$DATA" --workers 2   # ~30 min
# Round 0, MADP: 24 x 1000 steps x 32 samples (768k samples, ~11 passes over the 70k training split), ~100 min on one thread.
[ -f runs/madp-cpu/checkpoints/best/policy.safetensors ] || .venv/bin/madp train --model madp --preset cpu --data "$DATA" \
  --out runs/madp-cpu --threads 1 --epochs 24 --max-steps-per-epoch 1000 &
# Round 0, LPAC-K3: 6 x 1000 steps (192k samples), ~21 min on one thread.
[ -f runs/lpac-r0/checkpoints/best/policy.safetensors ] || .venv/bin/madp train --model lpac --preset cpu --data "$DATA" \
  --out runs/lpac-r0 --threads 1 --epochs 6 --max-steps-per-epoch 1000 &
wait
DATA=$DATA MADP0=runs/madp-cpu/checkpoints/best/policy.safetensors LPAC0=runs/lpac-r0/checkpoints/best/policy.safetensors \
  MADP_ROUNDS=2 LPAC_ROUNDS=1 bash scripts/train_dagger.sh
mkdir -p madp/checkpoints
DATA=$DATA MADP2=runs/madp-r2/checkpoints/best/policy.safetensors bash scripts/train_rounds_3to5.sh
# Rounds 6-8: packed launches and --augment d4, then narrow features and 128-robot swarms
# (docs/reports/2026-12-03-packed-starts.md and 2026-12-03-relabelling.md)
R5=runs/madp-r5/checkpoints/best/policy.safetensors bash scripts/train_rounds_6to8.sh
cp runs/madp-r8/checkpoints/best/policy.safetensors madp/checkpoints/madp-cpu.safetensors
cp runs/lpac-r1/checkpoints/best/policy.safetensors madp/checkpoints/lpac-cpu.safetensors
.venv/bin/python scripts/provenance.py runs/madp-r8 runs/lpac-r1
