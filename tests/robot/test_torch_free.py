"""The madp-robot wheel (robot/pyproject.toml) is whole and torch-free, checked in the dev environment
without installing it: every module it ships imports in a process where torch, and every madp module
the wheel does not ship, cannot be imported."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import textwrap

from tests.robot.wheel_testutils import REPO, module_name, wheel_files, wheel_modules

BLOCKER = textwrap.dedent("""
    import importlib, importlib.abc, json, sys

    SHIPPED, IMPORTED = set(json.loads(sys.argv[1])), json.loads(sys.argv[2])

    class Blocker(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] == "torch":
                raise ModuleNotFoundError(f"No module named {name!r} (blocked: madp-robot has no torch)", name=name)
            if name.split(".")[0] == "madp" and name not in SHIPPED:
                raise ModuleNotFoundError(f"No module named {name!r} (not in the madp-robot wheel)", name=name)
            return None

    sys.meta_path.insert(0, Blocker())
    failed = {}
    for module in IMPORTED:
        try:
            importlib.import_module(module)
        except ImportError as e:
            failed[module] = str(e)
    loaded = sorted({m.split(".")[0] for m, v in sys.modules.items() if v is not None} & {"torch", "torch_geometric"})
    print(json.dumps({"failed": failed, "loaded": loaded}))
""")


def test_the_wheel_ships_the_robot_package_and_the_torch_free_layers():
    files = wheel_files()
    assert all(src.is_file() for src in files.values()), [w for w, s in files.items() if not s.is_file()]
    modules = set(wheel_modules())
    assert {"madp", "madp.errors", "madp.io", "madp.sim", "madp.robot", "madp.robot.cli", "madp.robot.__main__",
            "madp.robot.runtime"} <= modules
    robot = {f"madp.robot.{p.stem}" for p in (REPO / "madp" / "robot").glob("*.py") if p.stem != "__init__"}
    assert robot <= modules  # madp/robot whole: a robot module added later ships without a change here
    assert not {"madp.sim.bench", "madp.sim.reference", "madp.io.ray_backend", "madp.models"} & modules


def test_every_module_of_the_wheel_imports_without_torch():
    modules = wheel_modules()
    r = subprocess.run([sys.executable, "-c", BLOCKER, json.dumps(modules), json.dumps(modules)], capture_output=True,
                       text=True, cwd=REPO, timeout=300)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.splitlines()[-1])
    assert out["failed"] == {}, ("modules of robot/pyproject.toml's wheel that import torch or a madp module it does "
                                 f"not ship (add that to its force-include table, or import it lazily): {out['failed']}")
    assert out["loaded"] == []


def test_the_blocker_catches_torch_and_modules_outside_the_wheel():
    """The check above can fail: a module of madp outside the wheel, and torch itself, do not import."""
    r = subprocess.run([sys.executable, "-c", BLOCKER, json.dumps(["madp", "madp.errors"]),
                        json.dumps(["madp.errors", "madp.models", "torch"])],
                       capture_output=True, text=True, cwd=REPO, timeout=300)
    failed = json.loads(r.stdout.splitlines()[-1])["failed"]
    assert set(failed) == {"madp.models", "torch"}
    assert "not in the madp-robot wheel" in failed["madp.models"] and "blocked" in failed["torch"]


def _imports(path, module: str) -> list[tuple[int, str, str | None]]:
    """``(line, module, name)`` of every import statement of ``path`` (module ``module``), function-level
    ones included; relative imports resolved; ``name`` is None for ``import M``."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name, None) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(up + ([node.module] if node.module else []))
            out += [(node.lineno, base, a.name) for a in node.names]
    return out


def test_no_import_anywhere_in_the_wheel_reaches_torch_or_outside_it():
    """Imports inside functions too (the command line's subcommands, the runtime's onnxruntime): none names
    torch, and every madp module named is one the wheel ships."""
    shipped = set(wheel_modules())
    bad = []
    for wheel_path, src in wheel_files().items():
        for line, module, name in _imports(src, module_name(wheel_path)):
            top = module.split(".")[0]
            if top in ("torch", "torch_geometric"):
                bad.append(f"{wheel_path}:{line} imports {module}")
            elif top == "madp" and module not in shipped and f"{module}.{name}" not in shipped:
                bad.append(f"{wheel_path}:{line} imports {module}{'.' + name if name else ''}, not in the wheel")
    assert not bad, bad
