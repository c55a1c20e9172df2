#!/usr/bin/env bash
# Set up madp in ./.venv and run the whole pipeline on small defaults (a few minutes on 2 CPU cores):
# generate a small expert dataset, train MADP and LPAC-K3 for one short epoch, evaluate on 2 environments.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/pip install -q torch==2.13.0 uv==0.13.8   # pip: the CPU torch on this disk; uv: the rest, in seconds
.venv/bin/uv pip install --python .venv/bin/python -q -e . torch==2.13.0
rm -rf runs/quickstart-madp runs/quickstart-lpac
.venv/bin/madp datagen --n 2000 --out data/quickstart --overwrite
.venv/bin/madp train --model madp --data data/quickstart --out runs/quickstart-madp --epochs 1 --max-steps-per-epoch 30
.venv/bin/madp train --model lpac --data data/quickstart --out runs/quickstart-lpac --epochs 1 --max-steps-per-epoch 30
.venv/bin/madp eval --suite uniform --num-envs 2 --steps 100 --out runs/quickstart-eval --overwrite \
  --controllers clairvoyant,dcvt,lpac,madp \
  --lpac runs/quickstart-lpac/checkpoints/latest/policy.safetensors \
  --madp runs/quickstart-madp/checkpoints/latest/policy.safetensors
