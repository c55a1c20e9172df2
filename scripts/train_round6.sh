#!/usr/bin/env bash
# MADP round 6 (README, Exploration from packed starts): round 5 (the shipped policy before it) trained
# on the starts that matter. The round-5 policy's own rollouts from packed training launches (random
# boxes, bands in any orientation, clusters: `madp datagen --launch packed`) and from uniform launches
# are relabelled by the expert, expert rollouts from packed launches added, and the whole set trained
# with the world's 8 rotations and reflections (`--augment d4`), warm-started from round 5.
# Dataset seeds 0 and 601-603 are training seeds; the evaluation suites' seeds never are (madp.eval.suites).
# ~20 min of relabelling rollouts and ~35 min of training on one thread each.
set -euo pipefail
D=${DATA6:-/work/data}
R5=${R5:-madp/checkpoints/madp-cpu.safetensors}
OUT=${OUT:-runs/madp-r6}
AUGMENT=${AUGMENT:-d4}
[ -f "$D/r6-packed-dagger/manifest.json" ] || .venv/bin/madp datagen --n 10000 --seed 601 --policy "$R5" --beta 0 \
  --launch packed --out "$D/r6-packed-dagger" --workers 1
[ -f "$D/r6-packed-expert/manifest.json" ] || .venv/bin/madp datagen --n 10000 --seed 602 --launch packed \
  --out "$D/r6-packed-expert" --workers 1
[ -f "$D/expert30k/manifest.json" ] || .venv/bin/madp datagen --n 30000 --seed 0 --out "$D/expert30k" --workers 1
[ -f "$D/r6-uniform-dagger/manifest.json" ] || .venv/bin/madp datagen --n 5000 --seed 603 --policy "$R5" --beta 0 \
  --out "$D/r6-uniform-dagger" --workers 1
.venv/bin/madp train --model madp --preset cpu --data "$D/expert30k" --data "$D/r6-uniform-dagger" \
  --data "$D/r6-packed-expert" --data "$D/r6-packed-dagger" --data-weights 1,2,2,3 --init "$R5" \
  --augment "$AUGMENT" --lr 1e-4 --out "$OUT" --threads 1 --epochs 3 --max-steps-per-epoch 1000 --seed 106
