"""Print the README's results table from runs/eval/<suite>/summary.json (ours beside the paper's)."""

import json
import sys
from pathlib import Path

PAPER = {"uniform": {"dcvt": 0.72, "lpac": 0.48, "madp": 0.46}, "cities": {"dcvt": 0.63, "lpac": 0.45, "madp": 0.39}}
NAMES = {"clairvoyant": "clairvoyant CVT", "dcvt": "DCVT", "lpac": "LPAC-K3", "madp": "MADP (decentralized)",
         "madp_central": "MADP (centralized-masked)"}
root = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/eval")
print("| suite | controller | ours: J(600)/J(0), mean ± SE [95% CI] | n | paper | ms per step |")
print("|---|---|---|---|---|---|")
for suite in ("uniform", "cities"):
    f = root / suite / "summary.json"
    if not f.exists():
        continue
    s = json.loads(f.read_text())
    for c in s["controllers"]:
        o = s["overall"][c]
        paper = PAPER[suite].get("madp" if c.startswith("madp") else c, "")
        se = f" ± {o['se']:.3f}" if o["se"] is not None else ""
        print(f"| {suite} | {NAMES.get(c, c)} | {o['mean']:.3f}{se} [{o['ci_lo']:.3f}, {o['ci_hi']:.3f}] | {o['n']} | "
              f"{paper} | {o['mean_step_ms']:.0f} |")
