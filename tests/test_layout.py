"""The shape of the house (issue 27), checked on the source: one definition of the controller names,
inference never imports training, small modules, a thin command line, and ``__init__.py`` files that
only re-export."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from madp.controllers import CHECKPOINT_KINDS, NAMES

MADP = Path(__file__).resolve().parents[1] / "madp"
MODULES = sorted(MADP.rglob("*.py"))


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), str(path))


def _rel(path: Path) -> str:
    return str(path.relative_to(MADP.parent))


def test_modules_are_small_and_the_command_line_thin():
    long = {_rel(p): n for p in MODULES if (n := len(p.read_text(encoding="utf-8").splitlines())) > 500}
    assert not long, f"modules over 500 lines: {long}"
    assert len((MADP / "cli.py").read_text(encoding="utf-8").splitlines()) <= 350


def test_init_files_only_re_export():
    """A docstring, imports and ``__all__`` (and the package's ``__version__``); no other statement."""
    for path in MADP.rglob("__init__.py"):
        for i, node in enumerate(_tree(path).body):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            if i == 0 and isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
                continue  # the docstring
            targets = [t.id for t in getattr(node, "targets", []) if isinstance(t, ast.Name)]
            assert isinstance(node, ast.Assign) and targets in (["__all__"], ["__version__"]), \
                f"{_rel(path)}:{node.lineno}: code in an __init__.py"


def test_policies_never_import_training():
    for path in (MADP / "policies").rglob("*.py"):
        for node in ast.walk(_tree(path)):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            assert not any(n == "madp.training" or n.startswith("madp.training.") for n in names), \
                f"{_rel(path)}:{node.lineno} imports madp.training"


@pytest.mark.parametrize("path", MODULES, ids=_rel)
def test_controller_names_are_listed_only_in_the_registry(path):
    """No literal tuple, list, set or dict outside ``madp/controllers.py`` names two controllers: every
    list, order or kind of controllers derives from :data:`madp.controllers.CONTROLLERS`. (A pair of the
    checkpoint kinds ``lpac`` / ``madp`` is a list of kinds; the paper's table is keyed by the paper's
    names for its controllers.)"""
    if path in (MADP / "controllers.py", MADP / "eval" / "paper.py"):
        return
    for node in ast.walk(_tree(path)):
        items = node.keys if isinstance(node, ast.Dict) else getattr(node, "elts", None)
        if isinstance(node, (ast.Tuple, ast.List, ast.Set, ast.Dict)) and items:
            named = {x.value for x in items if isinstance(x, ast.Constant) and x.value in NAMES}
            assert len(named) < 2 or named <= set(CHECKPOINT_KINDS), \
                f"{_rel(path)}:{node.lineno} lists controllers {sorted(named)}"
