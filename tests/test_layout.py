"""The shape of the house, checked on the source: one definition of the controller names, inference
never imports training, small modules, a thin command line, ``__init__.py`` files that only re-export,
and no import circle among madp's modules."""

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


def test_no_top_level_room_holds_more_than_a_share_of_the_lines():
    """Each top-level package (or module) of ``madp/`` holds at most 15 % of its Python lines: a room
    that grows past that does more than one trade and is split."""
    lines: dict[str, int] = {}
    for p in MODULES:
        top = p.relative_to(MADP).parts[0]
        lines[top] = lines.get(top, 0) + len(p.read_text(encoding="utf-8").splitlines())
    total = sum(lines.values())
    big = {top: f"{n / total:.1%}" for top, n in lines.items() if n > 0.15 * total}
    assert not big, f"top-level rooms over 15 % of madp/'s lines: {big}"


def test_the_command_modules_live_in_one_package_beside_the_app():
    """``madp/cli.py`` is the app; the command modules it gathers are in ``madp/commands/``, none beside it."""
    assert not sorted(p.name for p in MADP.glob("cli_*.py"))
    assert (MADP / "commands" / "main.py").is_file()


def test_private_names_of_the_model_bench_stay_in_models():
    """Outside ``madp/models/``, nothing imports a name starting with ``_`` from ``madp.models.bench``."""
    for path in MODULES:
        if path.is_relative_to(MADP / "models"):
            continue
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.ImportFrom) and node.module == "madp.models.bench":
                private = [a.name for a in node.names if a.name.startswith("_")]
                assert not private, f"{_rel(path)}:{node.lineno} imports {private} from madp.models.bench"


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


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(MADP.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported_modules(path: Path, known: set[str]) -> set[str]:
    """The madp modules ``path`` imports, anywhere in the file (module level and inside functions).
    ``from P import x`` counts as importing ``P.x`` when that is a module, else ``P``; a name that is
    not a module counts as its nearest enclosing module."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(up + ([node.module] if node.module else []))
            found.update(f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names)
    out = set()
    for m in found:
        while m and m not in known:
            m = m.rpartition(".")[0]
        if m and m != name:
            out.add(m)
    return out


def import_cycles() -> list[list[str]]:
    """The import circles among madp's modules: each strongly connected set of two or more modules of
    the graph "module imports module" (every import statement, function-level ones included)."""
    known = {_module_name(p) for p in MODULES}
    graph = {_module_name(p): sorted(_imported_modules(p, known)) for p in MODULES}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def test_no_import_circle_among_madp_modules():
    assert import_cycles() == []


def test_the_import_circle_check_finds_a_circle(tmp_path, monkeypatch):
    """The check itself: two modules that import each other, one inside a function, are a circle."""
    pkg = tmp_path / "madp"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from madp import b\n")
    (pkg / "b.py").write_text("def f():\n    from .a import x\n")
    monkeypatch.setitem(globals(), "MADP", pkg)
    monkeypatch.setitem(globals(), "MODULES", sorted(pkg.rglob("*.py")))
    assert import_cycles() == [["madp.a", "madp.b"]]
