#!/usr/bin/env bash
# Set up ./.venv: PyTorch first, the torch you choose, then madp with the extras given (comma-separated, e.g.
# "dev,docs"; none: madp alone). scripts/quickstart.sh and .ci/run call this; run it alone to install only.
#
#   MADP_TORCH_INDEX  a package index for torch alone, e.g. PyTorch's own CPU wheels,
#                     https://download.pytorch.org/whl/cpu (a CPU-only machine: ~200 MB), or a CUDA build's,
#                     https://download.pytorch.org/whl/cu126. Unset: PyPI, whose Linux torch is the CUDA build
#                     (several GB, what a GPU machine wants), unless pip's own configuration finds another.
#   MADP_TORCH        what to install as torch: a requirement or a wheel file [torch==2.13.0]
#
# Usage: [MADP_TORCH_INDEX=URL] [MADP_TORCH=SPEC] bash scripts/setup_venv.sh [EXTRAS]
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRAS=${1:-}
TORCH=${MADP_TORCH:-torch==2.13.0}
INDEX=()
[ -z "${MADP_TORCH_INDEX:-}" ] || INDEX=(--index-url "$MADP_TORCH_INDEX")
python3 -m venv .venv
.venv/bin/pip install -q ${INDEX[@]+"${INDEX[@]}"} "$TORCH"
# uv installs the rest in seconds where pip takes ~1.5 min. torch is pinned to the build just installed (e.g.
# 2.13.0+cpu), which that install satisfies, so uv neither fetches another nor takes a newer (CUDA) torch that
# the newest torchvision would ask for
.venv/bin/pip install -q uv==0.13.8
TORCH_VERSION=$(.venv/bin/python -c 'import importlib.metadata as m; print(m.version("torch"))')
.venv/bin/uv pip install --python .venv/bin/python -q -e ".${EXTRAS:+[$EXTRAS]}" "torch==$TORCH_VERSION"
.venv/bin/madp --version   # the install check: madp's and torch's versions, torch's build and the GPU it sees
