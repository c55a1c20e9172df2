"""Mutation sample of the numba kernels (issue 17). mutmut skips decorated functions, so it never
mutates ``madp/sim/kernels.py`` (every function there is ``@numba.njit``). This script applies mutmut's
kinds of operator mutation to a deterministic random sample of the file's sites, one at a time, in a
scratch copy of the package (fresh ``NUMBA_CACHE_DIR`` each), runs the simulator tests that call the
kernels, and writes each verdict with its diff to ``runs/mutation/kernels.txt``.

    .venv/bin/python scripts/mutation_kernels.py [--sample 30] [--seed 0] [--tests tests/sim/test_kernels.py ...]

A mutant is *killed* when the tests fail (or time out), *survived* when they pass. Mutation kinds:
comparison flips (< <=, > >=, == !=), + <-> -, * -> /, augmented += <-> -=, integer constant n -> n + 1,
``break`` -> ``continue``. The unmutated file is run first as a control: it must pass.
"""

from __future__ import annotations

import argparse
import ast
import copy
import difflib
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KERNELS = ROOT / "madp" / "sim" / "kernels.py"
SWAP = {ast.Lt: ast.LtE, ast.LtE: ast.Lt, ast.Gt: ast.GtE, ast.GtE: ast.Gt, ast.Eq: ast.NotEq, ast.NotEq: ast.Eq,
        ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div}


def sites(tree: ast.Module) -> list[tuple[int, str]]:
    """(node index in ast.walk order, kind) of every mutable site inside a function."""
    out = []
    for i, node in enumerate(ast.walk(tree)):
        if isinstance(node, ast.Compare) and len(node.ops) == 1 and type(node.ops[0]) in SWAP:
            out.append((i, "compare"))
        elif isinstance(node, (ast.BinOp, ast.AugAssign)) and type(node.op) in SWAP:
            out.append((i, "binop"))
        elif isinstance(node, ast.Constant) and type(node.value) is int and not isinstance(node.value, bool):
            out.append((i, "int"))
        elif isinstance(node, ast.Break):
            out.append((i, "break"))
    return out


def mutate(tree: ast.Module, index: int) -> ast.Module:
    t = copy.deepcopy(tree)
    parents = {child: node for node in ast.walk(t) for child in ast.iter_child_nodes(node)}
    node = list(ast.walk(t))[index]
    if isinstance(node, ast.Compare):
        node.ops = [SWAP[type(node.ops[0])]()]
    elif isinstance(node, (ast.BinOp, ast.AugAssign)):
        node.op = SWAP[type(node.op)]()
    elif isinstance(node, ast.Constant):
        node.value = node.value + 1
    elif isinstance(node, ast.Break):
        parent = parents[node]
        for field in ("body", "orelse"):
            body = getattr(parent, field, [])
            if node in body:
                body[body.index(node)] = ast.Continue()
    return t


def run_tests(source: str, tests: list[str], timeout: float) -> tuple[str, float]:
    with tempfile.TemporaryDirectory(prefix="kmut-") as tmp:
        pkg = Path(tmp) / "pkg"
        shutil.copytree(ROOT / "madp", pkg / "madp", ignore=shutil.ignore_patterns("__pycache__", "checkpoints"))
        (pkg / "madp" / "checkpoints").symlink_to(ROOT / "madp" / "checkpoints")
        (pkg / "madp" / "sim" / "kernels.py").write_text(source)
        env = dict(os.environ, PYTHONPATH=str(pkg), NUMBA_CACHE_DIR=str(Path(tmp) / "numba"), OMP_NUM_THREADS="1")
        t0 = time.perf_counter()
        try:
            r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "--import-mode=append",
                                *[str(ROOT / t) for t in tests]], cwd=tmp, env=env, capture_output=True, text=True,
                               timeout=timeout)
            verdict = "survived" if r.returncode == 0 else "killed"
        except subprocess.TimeoutExpired:
            verdict = "timeout"
        return verdict, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sample", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=600)
    ap.add_argument("--tests", nargs="+", default=["tests/sim/test_kernels.py", "tests/sim/test_vectors.py",
                                                   "tests/sim/test_geometry.py"])
    ap.add_argument("--out", default=str(ROOT / "runs" / "mutation" / "kernels.txt"))
    args = ap.parse_args()
    original = KERNELS.read_text()
    tree = ast.parse(original)
    base = ast.unparse(tree)
    all_sites = sites(tree)
    picked = sorted(random.Random(args.seed).sample(all_sites, min(args.sample, len(all_sites))))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    verdict, secs = run_tests(base, args.tests, args.timeout)
    if verdict != "survived":
        sys.exit(f"control run (unmutated kernels.py via ast.unparse) did not pass: {verdict}")
    lines = [f"# kernels.py mutation sample: {len(picked)} of {len(all_sites)} sites, seed {args.seed}; "
             f"tests {' '.join(args.tests)}; control passed in {secs:.0f} s\n"]
    counts: dict[str, int] = {}
    for n, (index, kind) in enumerate(picked, 1):
        mutated = ast.unparse(mutate(tree, index))
        diff = "".join(l for l in difflib.unified_diff(base.splitlines(True), mutated.splitlines(True), n=0)
                       if l[:1] in "+-" and l[:3] not in ("+++", "---"))
        verdict, secs = run_tests(mutated, args.tests, args.timeout)
        counts[verdict] = counts.get(verdict, 0) + 1
        lines.append(f"\n## site {index} ({kind}): {verdict} in {secs:.0f} s\n{diff}")
        print(f"[{n}/{len(picked)}] site {index} ({kind}): {verdict} ({secs:.0f} s)", flush=True)
        out.write_text("".join(lines) + f"\n# so far: {counts}\n")
    killed = counts.get("killed", 0) + counts.get("timeout", 0)
    summary = f"# {killed} of {len(picked)} killed ({100 * killed / max(len(picked), 1):.0f} %): {counts}\n"
    out.write_text("".join(lines) + summary)
    print(summary.strip("# \n"))


if __name__ == "__main__":
    main()
