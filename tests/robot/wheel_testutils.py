"""What the madp-robot tests share: the files and modules of the madp-robot wheel, read from
``robot/pyproject.toml`` (its ``force-include`` table maps madp's own source files into the wheel)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
ROBOT = REPO / "robot"


def wheel_files() -> dict[str, Path]:
    """``{path in the wheel: source file}`` of every Python file of the madp-robot wheel: each
    ``force-include`` entry of ``robot/pyproject.toml``, a directory expanded to its ``*.py`` files (as
    hatchling does, ``__pycache__`` left out)."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    table = tomllib.loads((ROBOT / "pyproject.toml").read_text())
    mapping = table["tool"]["hatch"]["build"]["targets"]["wheel"]["force-include"]
    files = {}
    for source, target in mapping.items():
        src = (ROBOT / source).resolve()
        if src.is_dir():
            files.update({f"{target}/{p.relative_to(src).as_posix()}": p for p in sorted(src.rglob("*.py"))
                          if "__pycache__" not in p.parts})
        else:
            files[target] = src
    return files


def module_name(wheel_path: str) -> str:
    """``madp/robot/__init__.py`` -> ``madp.robot``; ``madp/sim/env.py`` -> ``madp.sim.env``."""
    parts = wheel_path.removesuffix(".py").split("/")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def wheel_modules() -> list[str]:
    """The importable names of the wheel's modules and packages, sorted."""
    return sorted(module_name(p) for p in wheel_files())
