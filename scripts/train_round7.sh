#!/usr/bin/env bash
# MADP round 7 (README, Policy quality): round 6 (scripts/train_round6.sh) gave back part of what rounds
# 3-5 had bought on narrow features (sigma_5-10, sigma_10-20), because its mix had only σ ∈ [40, 60] m and
# 32-robot swarms. Round 7 adds the round-6 policy's own rollouts on maps with σ ∈ [5, 40] m and on
# 128-robot swarms (F = 32), relabelled by the expert, to round 6's mix, warm-started from round 6.
# Dataset seeds 701 and 752 are training seeds; the evaluation suites' seeds never are (madp.eval.suites).
# ~25 min of relabelling rollouts and ~30 min of training on one thread each.
set -euo pipefail
D=${DATA6:-/work/data}
R6=${R6:-madp/checkpoints/madp-cpu.safetensors}
OUT=${OUT:-runs/madp-r7}
[ -f "$D/r7-sigma-dagger/manifest.json" ] || .venv/bin/madp datagen --n 6000 --seed 701 --policy "$R6" --beta 0 \
  --sigma 5 40 --out "$D/r7-sigma-dagger" --workers 1
[ -f "$D/r7-n128-f32-dagger/manifest.json" ] || .venv/bin/madp datagen --n 1200 --seed 752 --num-robots 128 \
  --num-features 32 --policy "$R6" --beta 0 --out "$D/r7-n128-f32-dagger" --workers 1
.venv/bin/madp train --model madp --preset cpu --data "$D/expert30k" --data "$D/r6-uniform-dagger" \
  --data "$D/r6-packed-expert" --data "$D/r6-packed-dagger" --data "$D/r7-sigma-dagger" \
  --data "$D/r7-n128-f32-dagger" --data-weights 1,2,2,3,3,8 --init "$R6" \
  --augment d4 --lr 1e-4 --out "$OUT" --threads 1 --epochs 3 --max-steps-per-epoch 1000 --seed 107
