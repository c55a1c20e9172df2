"""The first command of each guide (``docs/guides/*.md``) and the same command at small sizes: what the
tests run to show that a guide opens with something a fresh clone runs."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

from tests.conftest import REPO
from tests.test_docs import code_blocks, shell_commands

GUIDES = sorted((REPO / "docs" / "guides").glob("*.md"))

#: Sizes a test shrinks, as (pattern, replacement): fewer samples, steps and environments; one worker
#: process where a command would start one per core (on Ray, Ray's own).
SMALL = (
    (r"--n \d+", "--n 16"),
    (r"--steps \d+", "--steps 3"),
    (r"--num-envs \d+", "--num-envs 1"),
    (r"max_steps=\d+", "max_steps=3"),
    (r"^madp (datagen|eval) (?!.*--ray)", r"madp \1 --workers 1 "),
)


def first_commands(guide: Path) -> list[str]:
    """The first command of ``guide``'s first code block: a Python block whole, else its first shell line
    that is not ``pip install`` (installing an extra is the Install page's; the tests' environment has
    every extra). A first command that writes ``s.json`` comes with the line that reads it."""
    text = guide.read_text(encoding="utf-8")
    first = re.search(r"^```(\w*)$", text, re.M)
    assert first, f"{guide.name}: no code block"
    if first.group(1) == "python":
        return [code_blocks(text, {"python"})[0]]
    block = code_blocks(text, {first.group(1)})[0]
    lines = [shlex.join(words) for words in shell_commands(f"```bash\n{block}```\n") if words[:2] != ["pip", "install"]]
    return lines[:2] if "--out s.json" in lines[0] else lines[:1]


def small(command: str) -> str:
    """``command`` with the sizes of :data:`SMALL` shrunk."""
    for pattern, replacement in SMALL:
        command = re.sub(pattern, replacement, command)
    return command
