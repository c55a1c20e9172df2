#!/usr/bin/env bash
# Rounds 3 and 4 of MADP (README, Policy quality; not shipped yet), on top of the shipped round-2 policy:
# round 3 relabels the shipped policy's own rollouts on narrow features (sigma 5-40 m), round 4 adds expert
# states of 128-robot swarms (datasets of several swarm sizes train together). ~25 + ~25 min on one thread.
# DATA and the round-1/2 relabelled sets as scripts/train_shipped.sh made them.
set -euo pipefail
DATA=${DATA:-/work/data100k}
CK=madp/checkpoints/madp-cpu.safetensors
[ -f "$DATA-madp-r3s/manifest.json" ] || .venv/bin/madp datagen --n 6000 --seed 301 --policy $CK --beta 0 \
  --sigma 5 40 --out "$DATA-madp-r3s" --workers 1
[ -f "$DATA-n128-f32/manifest.json" ] || .venv/bin/madp datagen --n 2000 --seed 311 --num-robots 128 \
  --num-features 32 --out "$DATA-n128-f32" --workers 1
[ -f "$DATA-n128-f16/manifest.json" ] || .venv/bin/madp datagen --n 1000 --seed 312 --num-robots 128 \
  --num-features 16 --out "$DATA-n128-f16" --workers 1
SETS=(--data "$DATA" --data "$DATA-madp-r1" --data "$DATA-madp-r2" --data "$DATA-madp-r3s")
.venv/bin/madp train --model madp --preset cpu "${SETS[@]}" --data-weights 1,4,4,4 --init $CK --lr 1e-4 \
  --out runs/madp-r3 --threads 1 --epochs 6 --max-steps-per-epoch 1000 --seed 103
.venv/bin/madp train --model madp --preset cpu "${SETS[@]}" --data "$DATA-n128-f32" --data "$DATA-n128-f16" \
  --data-weights 1,4,4,4,3,3 --init runs/madp-r3/checkpoints/best/policy.safetensors --lr 1e-4 \
  --out runs/madp-r4 --threads 1 --epochs 4 --max-steps-per-epoch 1000 --seed 104
