"""Print the README's results tables from runs/eval/<suite>/summary.json, ours beside the paper's.

Usage: python scripts/results_table.py [EVAL_ROOT ...]   (default runs/eval)

The main table (uniform, cities) takes its rows from every EVAL_ROOT in turn (e.g. a second root that
ran decentralized MADP on fewer environments); the group tables come from the first.
"""

import json
import sys
from pathlib import Path

from madp.controllers import CONTROLLERS
from madp.eval.paper import paper_results  # SPEC §5: the paper's J(600)/J(0)


def name(controller: str) -> str:
    return CONTROLLERS[controller].description if controller in CONTROLLERS else controller


def paper(suite: str, row: str, controller: str) -> str:
    info = CONTROLLERS.get(controller)
    v = paper_results(suite, row).get(info.paper) if info is not None and info.paper else None
    return "" if v is None else f"{v:.2f}"


def cell(o: dict) -> str:
    se = f" ± {o['se']:.3f}" if o["se"] is not None else ""
    return f"{o['mean']:.3f}{se}"


def main_table(roots: list[Path]) -> None:
    """uniform and cities: one row per controller, with 95% CI, n and time per step."""
    print("| suite | controller | ours: J(600)/J(0), mean ± SE [95% CI] | n | paper | ms per step |")
    print("|---|---|---|---|---|---|")
    for suite in ("uniform", "cities"):
        for root in roots:
            f = root / suite / "summary.json"
            if f.exists():
                main_rows(json.loads(f.read_text()), suite)


def main_rows(s: dict, suite: str) -> None:
    """One row per controller of a suite's summary; the paper's number is its suite mean (row "all")."""
    for c in s["controllers"]:
        o = s["overall"][c]
        print(f"| {suite} | {name(c)} | {cell(o)} [{o['ci_lo']:.3f}, {o['ci_hi']:.3f}] | {o['n']} | "
              f"{paper(suite, 'all', c)} | {o['mean_step_ms']:.0f} |")


def group_table(root: Path, suite: str) -> None:
    """sigma, launch, scale: one row per group, one column per controller (paper in brackets)."""
    f = root / suite / "summary.json"
    if not f.exists():
        return
    s = json.loads(f.read_text())
    cs = s["controllers"]
    print(f"\n**{suite}** (n per group: {s['by_group'][s['groups'][0]][cs[0]]['n']})\n")
    print("| group | " + " | ".join(name(c) for c in cs) + " |")
    print("|---|" + "---|" * len(cs))
    for g in s["groups"]:
        row = []
        for c in cs:
            o = s["by_group"][g].get(c)
            p = paper(suite, g, c)
            row.append("—" if o is None else cell(o) + (f" (paper {p})" if p else ""))
        print(f"| {g} | " + " | ".join(row) + " |")


if __name__ == "__main__":
    roots = [Path(a) for a in sys.argv[1:]] or [Path("runs/eval")]
    main_table(roots)
    for suite in ("sigma", "launch", "scale"):
        group_table(roots[0], suite)
