"""Write madp/checkpoints/provenance.json: how the shipped checkpoints were made.

Usage: python scripts/provenance.py DATA_DIR RUN_DIR [RUN_DIR ...] [MODEL="note" ...]
"""

import hashlib
import json
import subprocess
import sys
from pathlib import Path

root = Path(__file__).resolve().parents[1]
data, runs = Path(sys.argv[1]), [Path(p) for p in sys.argv[2:]]
manifest = json.loads((data / "manifest.json").read_text())
commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True).stdout.strip()
notes = dict(arg.split("=", 1) for arg in sys.argv[2:] if "=" in arg)
runs = [r for r in runs if "=" not in str(r)]
record = {
    "code_version": manifest["code_version"],
    "git_commit": commit,
    "dataset": {
        "command": manifest["created_by"],
        "seed": manifest["params"]["seed"],
        "num_samples": sum(sum(s["num_samples"] for s in sp["shards"]) for sp in manifest["splits"].values()),
        "manifest_sha256": hashlib.sha256((data / "manifest.json").read_bytes()).hexdigest(),
        "action_stats": manifest["action_stats"],
    },
    "checkpoints": {},
}
for run in runs:
    cfg = json.loads((run / "config.json").read_text())
    lines = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    vals = [d for d in lines if "val_loss" in d]
    t = cfg["train"]
    name = f"{t['model']}-{t['preset']}.safetensors"
    f = root / "madp" / "checkpoints" / name
    record["checkpoints"][name] = {
        "command": (f"madp train --model {t['model']} --preset {t['preset']} --data DATA --out {t['out']} --threads 1 "
                    f"--epochs {t['epochs']} --max-steps-per-epoch {t['max_steps_per_epoch']} --workers {t['num_workers']}"),
        "train_config": t,
        "num_parameters": cfg["num_parameters"],
        "source": "checkpoints/best/policy.safetensors",
        "steps": max(d.get("step", 0) for d in lines),
        "epochs_run": len(vals),
        "best_val_loss": min(d["val_loss"] for d in vals),
        "best_step": min(vals, key=lambda d: d["val_loss"])["step"],
        "samples_seen_at_best": min(vals, key=lambda d: d["val_loss"])["step"] * t["batch_size"],
        "val_loss_by_epoch": [d["val_loss"] for d in vals],
        "bytes": f.stat().st_size if f.exists() else None,
        "sha256": hashlib.sha256(f.read_bytes()).hexdigest() if f.exists() else None,
        "note": notes.get(t["model"], ""),
    }
out = root / "madp" / "checkpoints" / "provenance.json"
out.write_text(json.dumps(record, indent=1) + "\n")
print(out)
