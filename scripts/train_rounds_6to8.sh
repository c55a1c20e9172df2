#!/usr/bin/env bash
# MADP rounds 6-8 (docs/reports/2026-12-03-packed-starts.md and 2026-12-03-relabelling.md), each warm-started from the
# one before on the mix so far plus the new sets:
#   round 6: the round-5 policy's own rollouts from packed training launches (random boxes, bands in any
#            orientation, clusters: `madp datagen --launch packed`) and from uniform launches, relabelled by
#            the expert, plus expert rollouts from packed launches, trained with the world's 8 rotations and
#            reflections (`--augment d4`);
#   round 7: the round-6 policy's own rollouts on narrow features (σ ∈ [5, 40] m) and on 128-robot swarms
#            (F = 32), relabelled: round 6 had given back part of what rounds 3-5 bought there;
#   round 8: the round-7 policy's own rollouts on narrow features (σ ∈ [5, 25] m), relabelled, trained
#            twice as long (6 × 1000 steps, as round 3).
# Dataset seeds 0, 601-603, 701, 752 and 801 are training seeds; the evaluation suites' seeds never are
# (madp.eval.suites). Relabelling ~20 + ~25 + ~10 min, training ~35 + ~15 + ~30 min, one thread each.
# R5: the round-5 policy (scripts/train_rounds_3to5.sh). ROUNDS: the last round to run (6, 7 or 8).
set -euo pipefail
D=${DATA6:-data}
R5=${R5:-runs/madp-r5/checkpoints/best/policy.safetensors}
ROUNDS=${ROUNDS:-8}
best() { echo "runs/madp-r$1/checkpoints/best/policy.safetensors"; }
datagen() {  # datagen NAME ARGS...: a dataset of $D, made once
  local name=$1; shift
  [ -f "$D/$name/manifest.json" ] || .venv/bin/madp datagen "$@" --out "$D/$name" --workers 1
}
train() {  # train ROUND INIT WEIGHTS EPOCHS: one round on the sets so far
  [ -f "$(best "$1")" ] || .venv/bin/madp train --model madp --preset cpu "${SETS[@]}" --data-weights "$3" \
    --init "$2" --augment d4 --lr 1e-4 --out "runs/madp-r$1" --threads 1 --epochs "$4" \
    --max-steps-per-epoch 1000 --seed $((100 + $1))
}

datagen r6-packed-dagger --n 10000 --seed 601 --policy "$R5" --beta 0 --launch packed
datagen r6-packed-expert --n 10000 --seed 602 --launch packed
datagen expert30k --n 30000 --seed 0
datagen r6-uniform-dagger --n 5000 --seed 603 --policy "$R5" --beta 0
SETS=(--data "$D/expert30k" --data "$D/r6-uniform-dagger" --data "$D/r6-packed-expert" --data "$D/r6-packed-dagger")
train 6 "$R5" 1,2,2,3 3
[ "$ROUNDS" -ge 7 ] || exit 0

datagen r7-sigma-dagger --n 6000 --seed 701 --policy "$(best 6)" --beta 0 --sigma 5 40
datagen r7-n128-f32-dagger --n 1200 --seed 752 --num-robots 128 --num-features 32 --policy "$(best 6)" --beta 0
SETS+=(--data "$D/r7-sigma-dagger" --data "$D/r7-n128-f32-dagger")
train 7 "$(best 6)" 1,2,2,3,3,8 3
[ "$ROUNDS" -ge 8 ] || exit 0

datagen r8-sigma-dagger --n 6000 --seed 801 --policy "$(best 7)" --beta 0 --sigma 5 25
SETS+=(--data "$D/r8-sigma-dagger")
train 8 "$(best 7)" 1,2,2,3,3,8,3 6
