#!/usr/bin/env bash
# Set up madp in ./.venv and run the whole pipeline on small defaults (a few minutes on 2 CPU cores, after the
# install): generate a small expert dataset, train MADP and LPAC-K3 for one short epoch, evaluate them beside the
# shipped checkpoints on 2 environments, and say in words what the table shows.
# Which torch it installs: MADP_TORCH_INDEX and MADP_TORCH (scripts/setup_venv.sh), e.g. on a CPU-only machine
#   MADP_TORCH_INDEX=https://download.pytorch.org/whl/cpu bash scripts/quickstart.sh
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup_venv.sh
rm -rf runs/quickstart-madp runs/quickstart-lpac
.venv/bin/madp datagen --n 2000 --out data/quickstart --overwrite
.venv/bin/madp train --model madp --data data/quickstart --out runs/quickstart-madp --epochs 1 --max-steps-per-epoch 30
.venv/bin/madp train --model lpac --data data/quickstart --out runs/quickstart-lpac --epochs 1 --max-steps-per-epoch 30
# Plain lpac / madp are the checkpoints shipped with madp; lpac:quickstart / madp:quickstart the ones just trained.
.venv/bin/madp eval --suite uniform --num-envs 2 --steps 100 --out runs/quickstart-eval --overwrite \
  --controllers clairvoyant,dcvt,lpac,lpac:quickstart=runs/quickstart-lpac/checkpoints/latest/policy.safetensors,madp,madp:quickstart=runs/quickstart-madp/checkpoints/latest/policy.safetensors
cat <<'EOF'

What you are looking at (runs/quickstart-eval/uniform/: summary.md above, cost_uniform.png):
  J(100)/J(0): the coverage cost after 100 control steps relative to the start, on 2 environments; lower is better.
  MADP, LPAC-K3: the checkpoints shipped with madp, trained for hours (their figures on the whole uniform
    suite, 50 environments x 600 steps: docs/reports/results.md).
  MADP:quickstart, LPAC-K3:quickstart: trained for 30 steps just now; LPAC-K3 barely moves the swarm, and
    MADP's progress comes mostly from the choice among its 4 samples: its file carries no critic, so it
    chooses by explore, the default's fallback (the note above says so).
  Clairvoyant: the expert that sees the whole map (an oracle, the floor); DCVT: the classical decentralized baseline.
  2 environments x 100 steps is a smoke test, not a measurement: the README's numbers are 50 x 600.
EOF
