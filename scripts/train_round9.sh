#!/usr/bin/env bash
# MADP round 9 (docs/reports/2026-12-04-deployed-states.md): relabel the states the deployed policy visits.
# The shipped round-8 policy drives at the evaluation default (decentralized, --frame d4, --select explore, K = 4)
# on uniform launches; the clairvoyant expert labels every state (`madp datagen --policy … --select explore`).
# Warm start from round 8 on the new set plus fresh expert data (the round-8 mix's relabelled sets came from
# policies that are not shipped), --augment d4, lr 1e-4, one thread.
# Dataset seeds 901 and 902 are training seeds; the evaluation suites' seeds never are (madp.eval.suites).
set -euo pipefail
D=${DATA9:-/work/data}
R8=${R8:-madp/checkpoints/madp-cpu.safetensors}
OUT=${OUT:-runs/madp-r9}
datagen() {  # datagen NAME ARGS...: a dataset of $D, made once
  local name=$1; shift
  [ -f "$D/$name/manifest.json" ] || .venv/bin/madp datagen "$@" --out "$D/$name" --workers 1
}
datagen r9-uniform-explore --n 8000 --seed 901 --policy "$R8" --beta 0 --select explore
datagen r9-expert --n 6000 --seed 902
[ -f "$OUT/checkpoints/best/policy.safetensors" ] || .venv/bin/madp train --model madp --preset cpu \
  --data "$D/r9-expert" --data "$D/r9-uniform-explore" --data-weights 1,3 --init "$R8" --augment d4 --lr 1e-4 \
  --out "$OUT" --threads 1 --epochs 3 --max-steps-per-epoch 1000 --seed 109
