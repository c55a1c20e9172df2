#!/usr/bin/env bash
# MADP rounds 3-5 (docs/reports/2026-12-03-relabelling.md), on top of the round-2 policy of scripts/train_dagger.sh:
#   round 3 relabels the round-2 policy's own rollouts on narrow features (sigma 5-40 m);
#   round 4 adds expert states of 128-robot swarms (datasets of several swarm sizes train together);
#   round 5 relabels the round-4 policy's own 128-robot rollouts (F = 16 and 32). Round 5 is shipped.
# ~25 + ~25 + ~45 min of training and ~45 min of relabelling rollouts on one thread each.
# DATA and the round-1/2 relabelled sets as scripts/train_shipped.sh made them; MADP2 the round-2 policy.
set -euo pipefail
DATA=${DATA:-data/expert-100k}
MADP2=${MADP2:-runs/madp-r2/checkpoints/best/policy.safetensors}
R3=runs/madp-r3/checkpoints/best/policy.safetensors
R4=runs/madp-r4/checkpoints/best/policy.safetensors
[ -f "$DATA-madp-r3s/manifest.json" ] || .venv/bin/madp datagen --n 6000 --seed 301 --policy "$MADP2" --beta 0 \
  --sigma 5 40 --out "$DATA-madp-r3s" --workers 1
[ -f "$DATA-n128-f32/manifest.json" ] || .venv/bin/madp datagen --n 2000 --seed 311 --num-robots 128 \
  --num-features 32 --out "$DATA-n128-f32" --workers 1
[ -f "$DATA-n128-f16/manifest.json" ] || .venv/bin/madp datagen --n 1000 --seed 312 --num-robots 128 \
  --num-features 16 --out "$DATA-n128-f16" --workers 1
SETS=(--data "$DATA" --data "$DATA-madp-r1" --data "$DATA-madp-r2" --data "$DATA-madp-r3s")
[ -f $R3 ] || .venv/bin/madp train --model madp --preset cpu "${SETS[@]}" --data-weights 1,4,4,4 --init "$MADP2" \
  --lr 1e-4 --out runs/madp-r3 --threads 1 --epochs 6 --max-steps-per-epoch 1000 --seed 103
SETS+=(--data "$DATA-n128-f32" --data "$DATA-n128-f16")
[ -f $R4 ] || .venv/bin/madp train --model madp --preset cpu "${SETS[@]}" --data-weights 1,4,4,4,3,3 --init $R3 \
  --lr 1e-4 --out runs/madp-r4 --threads 1 --epochs 4 --max-steps-per-epoch 1000 --seed 104
for f in 32 16; do
  [ -f "$DATA-madp-r5-n128-f$f/manifest.json" ] || .venv/bin/madp datagen --n 1200 --seed $((320 + f)) \
    --num-robots 128 --num-features $f --policy $R4 --beta 0 --out "$DATA-madp-r5-n128-f$f" --workers 1
done
SETS+=(--data "$DATA-madp-r5-n128-f32" --data "$DATA-madp-r5-n128-f16")
.venv/bin/madp train --model madp --preset cpu "${SETS[@]}" --data-weights 1,4,4,4,3,3,10,10 --init $R4 \
  --lr 1e-4 --out runs/madp-r5 --threads 1 --epochs 4 --max-steps-per-epoch 1000 --seed 105
