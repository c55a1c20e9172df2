"""Every guide opens with a command that runs on a fresh clone: each guide's first command (with the line
that reads the scenario file it writes) runs here at small sizes, in a folder holding only what a clone
holds. The GPU guide's script runs in tests/test_gpu_paper.py and the Ray guide's on the local Ray of
tests/test_ray.py, each with their own fixtures."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys

import pytest

from tests.conftest import REPO
from tests.guides import GUIDES, first_commands, small
from tests.test_reliability_errors import cli

#: Guides whose first command another test file runs, with the words it starts with.
ELSEWHERE = {"gpu.md": ("tests/test_gpu_paper.py", ["bash", "scripts/gpu_paper.sh"]),
             "ray.md": ("tests/test_ray.py", ["madp", "datagen"])}


@pytest.fixture(scope="module")
def clone(tmp_path_factory):
    """A folder with a fresh clone's files that the guides' commands read (the package with its
    checkpoints and city data, the docs' examples, the scripts) and nothing made."""
    root = tmp_path_factory.mktemp("clone")
    for name in ("madp", "docs", "scripts"):
        (root / name).symlink_to(REPO / name)
    return root


def run(command: str, cwd) -> None:
    words = shlex.split(command) if not command.startswith("from ") else ["python", "-c", command]
    if words[0] == "madp":
        code, err = cli(*words[1:])
        assert code == 0, f"{command}: {err[-3000:]}"
        return
    assert words[0] == "python", command
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]), OMP_NUM_THREADS="1")
    r = subprocess.run([sys.executable, *words[1:]], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, f"{command}: {r.stderr[-3000:]}"


def test_every_guides_first_command_runs_on_a_fresh_clone(clone, monkeypatch):
    monkeypatch.chdir(clone)
    done: set[str] = set()
    for guide in GUIDES:
        for command in map(small, first_commands(guide)):
            if guide.name in ELSEWHERE:
                test_file, words = ELSEWHERE[guide.name]
                assert shlex.split(command)[:2] == words, (guide.name, command)
                continue
            key = re.sub(r"--out \S+", "", command)  # the same command into another folder runs once
            if key not in done:
                run(command, clone)
                done.add(key)
    assert (clone / "s.json").is_file() and (clone / "rollout.mp4").is_file() and (clone / "data" / "small" / "manifest.json").is_file()


def test_the_first_commands_are_found_and_shrunk():
    firsts = {g.name: first_commands(g) for g in GUIDES}
    assert len(firsts) >= 12 and all(firsts.values())
    assert [small(c) for c in firsts["robots.md"]] == [
        "madp scenario import madp/cities/data/alameda_california.csv --out s.json",
        "madp rollout --scenario s.json --controller madp --network loss=0.3,max_age_steps=5 --steps 3 --out r.json"]
    assert small(firsts["datasets.md"][0]) == "madp datagen --workers 1 --n 16 --out data/small"
    assert small(firsts["ray.md"][0]) == "madp datagen --n 16 --out data/ray --ray"  # Ray's workers, not --workers
    assert firsts["export.md"] == ["madp export madp/checkpoints/madp-cpu.safetensors --out export/madp-cpu"]  # pip: Install's
    assert "max_steps=3" in small(firsts["environments.md"][0])
