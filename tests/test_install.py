"""The README's two commands install the torch a user names: scripts/quickstart.sh and .ci/run run in a copy
of their scripts with a stand-in ``python3`` first on PATH, whose ``venv`` holds tools that only log their
command lines, so what reaches pip and uv is seen without a network; ``madp --version`` names the build."""

from __future__ import annotations

import os
import re
import shutil
import stat
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from madp.cli import app
from madp.versions import torch_build
from tests.conftest import REPO

CPU_INDEX = "https://download.pytorch.org/whl/cpu"
#: A stand-in python3: ``-m venv DIR`` makes DIR/bin/{pip,uv,madp,mkdocs,python}, each logging its command
#: line to $LOG; the venv's python prints an installed torch's version when asked for one.
FAKE_PYTHON = """#!/usr/bin/env bash
if [ "$1 $2" = "-m venv" ]; then
  mkdir -p "$3/bin"
  for tool in pip uv madp mkdocs; do
    printf '#!/usr/bin/env bash\\necho "%s $*" >> "$LOG"\\n' "$tool" > "$3/bin/$tool"
  done
  printf '#!/usr/bin/env bash\\ncase "$*" in *importlib.metadata*) echo 2.13.0+cpu ;; *) echo "python $*" >> "$LOG" ;; esac\\n' \\
    > "$3/bin/python"
  chmod +x "$3"/bin/*
else
  echo "python3 $*" >> "$LOG"
fi
"""


def run_command(tmp_path: Path, script: str, **env: str) -> list[str]:
    """Run ``bash SCRIPT`` of a copy of the scripts with the stand-in python3; the logged command lines."""
    clone = tmp_path / "clone"
    for rel in ("scripts/quickstart.sh", "scripts/setup_venv.sh", ".ci/run"):
        (clone / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / rel, clone / rel)
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "python3").write_text(FAKE_PYTHON)
    (bin_dir / "python3").chmod(stat.S_IRWXU)
    log = tmp_path / "log"
    environ = {k: v for k, v in os.environ.items() if not k.startswith("MADP_TORCH")}
    environ.update(PATH=f"{bin_dir}{os.pathsep}{environ['PATH']}", LOG=str(log), **env)
    r = subprocess.run(["bash", script], cwd=clone, env=environ, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return log.read_text().splitlines()


@pytest.mark.parametrize("script", ["scripts/quickstart.sh", ".ci/run"])
def test_the_torch_a_user_names_reaches_pip_and_uv_keeps_it(tmp_path, script):
    lines = run_command(tmp_path / "index", script, MADP_TORCH_INDEX=CPU_INDEX)
    assert f"pip install -q --index-url {CPU_INDEX} torch==2.13.0" in lines
    uv = next(line for line in lines if line.startswith("uv pip install"))
    assert uv.endswith("torch==2.13.0+cpu") and CPU_INDEX not in uv  # the rest from PyPI, torch as installed
    assert "madp --version" in lines
    assert lines[-1].startswith("madp eval --suite uniform" if script.endswith("quickstart.sh") else "python -m pytest")
    wheel = "/wheels/torch-2.13.0+cpu-cp311-cp311-manylinux_2_28_x86_64.whl"
    assert f"pip install -q {wheel}" in run_command(tmp_path / "wheel", script, MADP_TORCH=wheel)
    default = run_command(tmp_path / "default", script)
    assert "pip install -q torch==2.13.0" in default and not any("--index-url" in line for line in default)


def test_the_install_pages_name_the_choice_and_the_check():
    for page in ("README.md", "docs/getting-started.md"):
        text = (REPO / page).read_text(encoding="utf-8")
        assert f"MADP_TORCH_INDEX={CPU_INDEX} bash scripts/quickstart.sh" in text, page
        assert f"pip install torch==2.13.0 --index-url {CPU_INDEX}" in text and "madp --version" in text, page


def test_madp_version_names_torchs_build():
    r = CliRunner().invoke(app, ["--version"])
    import torch

    assert r.exit_code == 0 and re.fullmatch(r"madp \S+ \(torch \S+, .+; Python \S+\)\n", r.output), r.output
    assert f"torch {torch.__version__}," in r.output
    assert torch_build("2.13.0+cpu", None, []) == "torch 2.13.0+cpu, CPU only"
    assert torch_build("2.13.0", "12.8", []) == "torch 2.13.0, CUDA 12.8 build, no GPU visible"
    assert torch_build("2.13.0", "12.8", ["H100", "H100"]) == "torch 2.13.0, CUDA 12.8: H100 and 1 more"


def test_no_script_defaults_to_a_path_outside_the_clone():
    """A recipe's data default is a folder of the clone (DATA=... overrides it), not one machine's path."""
    hits = [f"{p.name}: {m.group()}" for p in sorted((REPO / "scripts").glob("*.sh"))
            for m in re.finditer(r"\$\{\w+:-/[^}]*\}", p.read_text(encoding="utf-8"))]
    assert not hits, hits
