"""How many environments a paired comparison needs: the spread of MADP's paired differences in the kept results.

For every kept run of another setting (docs/results/), MADP's final cost J(T)/J(0) is paired with the kept
default's on the environments both ran (same suite, group and scenario seed), and the standard deviation of
the differences is taken per suite over all its environments. The median over runs is the suite's spread
σ_d; a suite no kept run pairs (``scale``) gets the largest of the others. ``madp eval --paired-se S``
reads the result to run, per suite, the n = ⌈(σ_d / S)²⌉ environments whose mean paired difference has
standard error S.

    python scripts/paired_sd.py            # print the table and write madp/eval/paired_sd.json
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
OUT = ROOT / "madp" / "eval" / "paired_sd.json"
#: The kept runs of the default, by directory prefix under docs/results.
DEFAULT_DIRS = ("default-2026-12-05", "launch-groups-2026-12-05/default", "sigma-2026-12-05/default",
                "faults-2026-12-05/madp/")
#: A run pairs a suite when it shares at least this many environments with the default.
MIN_PAIRS = 10


def _madp_costs(path: Path) -> dict[tuple[str, str, int], float]:
    t = pq.read_table(path, columns=["suite", "group", "scenario_seed", "controller", "final_cost"]).to_pydict()
    return {(s, g, seed): j for s, g, seed, c, j in
            zip(t["suite"], t["group"], t["scenario_seed"], t["controller"], t["final_cost"]) if c == "madp"}


def main() -> int:
    runs = {str(f.parent.relative_to(RESULTS)): _madp_costs(f) for f in sorted(RESULTS.rglob("results.parquet"))}
    default = {k: v for name, d in runs.items() if name.startswith(DEFAULT_DIRS) for k, v in d.items()}
    spreads: dict[str, list[tuple[str, int, float]]] = {}
    for name, costs in runs.items():
        if name.startswith(DEFAULT_DIRS):
            continue
        by_suite: dict[str, list[float]] = {}
        for key, j in costs.items():
            if key in default:
                by_suite.setdefault(key[0], []).append(j - default[key])
        for suite, diffs in by_suite.items():
            if len(diffs) >= MIN_PAIRS:
                spreads.setdefault(suite, []).append((name, len(diffs), float(np.std(diffs, ddof=1))))
    table = {suite: {"sd": float(np.median([r[2] for r in rows])), "runs": len(rows),
                     "sd_range": [min(r[2] for r in rows), max(r[2] for r in rows)]}
             for suite, rows in sorted(spreads.items())}
    largest = max(v["sd"] for v in table.values())
    for suite in ("uniform", "sigma", "cities", "launch", "scale"):
        table.setdefault(suite, {"sd": largest, "runs": 0, "sd_range": None})
    print("| suite | kept runs paired | σ_d (median) | range | n for SE 0.01 | n for SE 0.005 |")
    print("|---|--:|--:|---|--:|--:|")
    for suite, v in table.items():
        rng = "—" if v["sd_range"] is None else f"{v['sd_range'][0]:.3f}–{v['sd_range'][1]:.3f}"
        print(f"| `{suite}` | {v['runs']} | {v['sd']:.3f} | {rng} | {math.ceil((v['sd'] / 0.01) ** 2)} "
              f"| {math.ceil((v['sd'] / 0.005) ** 2)} |")
    about = ("MADP's paired difference of final cost J(T)/J(0) against the kept default: per suite, the median over "
             "kept runs of another setting of the standard deviation over the suite's environments (sd); a suite "
             "without a kept pair takes the largest. Written by scripts/paired_sd.py.")
    OUT.write_text(json.dumps({"about": about, "suites": table}, indent=1) + "\n", encoding="utf-8")
    print(f"-> {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
