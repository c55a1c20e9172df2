#!/usr/bin/env bash
# Expert relabelling (DAgger) rounds on top of round-0 checkpoints (scripts/train_shipped.sh calls this):
# round k lets the round k-1 policy drive (madp datagen --policy, beta 0), labels the states it visits
# with the clairvoyant expert, and warm-starts round k from round k-1 on the expert data plus every
# relabelled set so far (each relabelled set x4 per epoch). docs/reports/2026-12-03-relabelling.md has what each round bought.
# Run from the repository root with MADP0/LPAC0 pointing at round-0 policies (LPAC-K3's is trained if missing).
set -euo pipefail
DATA=${DATA:-data/expert-100k}
MADP_ROUNDS=${MADP_ROUNDS:-2}
LPAC_ROUNDS=${LPAC_ROUNDS:-1}
MADP0=${MADP0:-runs/madp-cpu/checkpoints/best/policy.safetensors}
LPAC0=${LPAC0:-runs/lpac-r0/checkpoints/best/policy.safetensors}
# LPAC-K3's round 0 with today's recipe (AdamW, unweighted graph): 6 x 1000 steps, ~21 min on one thread
[ -f "$LPAC0" ] || .venv/bin/madp train --model lpac --preset cpu --data "$DATA" --out runs/lpac-r0 --threads 1 \
  --epochs 6 --max-steps-per-epoch 1000
for model in madp lpac; do
  prev=$([ $model = madp ] && echo "$MADP0" || echo "$LPAC0")
  seed0=$([ $model = madp ] && echo 100 || echo 200)
  steps=$([ $model = madp ] && echo 6 || echo 3)   # epochs of 1000 steps per round (~21 min / ~12 min on one thread)
  rounds=$([ $model = madp ] && echo "$MADP_ROUNDS" || echo "$LPAC_ROUNDS")
  sets=(--data "$DATA"); weights=1
  for k in $(seq 1 "$rounds"); do
    # ~18 min (MADP) / ~15 min (LPAC-K3) on one core for 10k samples (7k train)
    .venv/bin/madp datagen --n 10000 --seed $((seed0 + k)) --policy "$prev" --beta 0 --out "$DATA-$model-r$k" --workers 1
    sets+=(--data "$DATA-$model-r$k"); weights="$weights,4"
    .venv/bin/madp train --model $model --preset cpu "${sets[@]}" --data-weights "$weights" --init "$prev" --lr 1e-4 \
      --out runs/$model-r$k --threads 1 --epochs "$steps" --max-steps-per-epoch 1000
    prev=runs/$model-r$k/checkpoints/best/policy.safetensors
  done
done
