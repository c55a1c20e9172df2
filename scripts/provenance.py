"""Write madp/checkpoints/provenance.json: how each shipped checkpoint was made, round by round.

Usage: python scripts/provenance.py RUN_DIR [RUN_DIR ...]

Each RUN_DIR is a finished `madp train` run whose checkpoints/best/policy.safetensors is shipped as
madp/checkpoints/<model>-<preset>.safetensors (copy it there first). The record follows each run's
``--init`` back to its first round: a warm start from another run directory is recorded from that
run's files; a warm start from a file that no run directory describes (an earlier shipped checkpoint)
is recorded from the provenance.json already here, matched by sha256. Every dataset a round trained on
is listed with its command, seed, sample count and manifest sha256 — for relabelled (DAgger) sets also
the policy that drove their rollouts. Checkpoints not named keep their earlier record.
"""

import hashlib
import json
import subprocess
import sys
from pathlib import Path

root = Path(__file__).resolve().parents[1]
out = root / "madp" / "checkpoints" / "provenance.json"
previous = json.loads(out.read_text()) if out.exists() else {"checkpoints": {}}


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def dataset(path: str, weight: float) -> dict:
    d = Path(path)
    m = json.loads((d / "manifest.json").read_text())
    rec = {"command": m["created_by"], "seed": m["params"]["seed"], "weight_per_epoch": weight,
           "num_samples": sum(sum(s["num_samples"] for s in sp["shards"]) for sp in m["splits"].values()),
           "manifest_sha256": sha256(d / "manifest.json")}
    if "policy" in m["params"]:
        p = m["params"]["policy"]
        rec["driven_by"] = {"path": p["path"], "sha256": p["sha256"], "kind": p["kind"], "beta": p["beta"]}
    return rec


def earlier_record(sha: str) -> dict:
    """The record of a shipped checkpoint with this sha256 in the existing provenance.json."""
    for name, rec in previous["checkpoints"].items():
        if rec.get("sha256") == sha:
            return {"checkpoint": name, "git_commit": previous.get("git_commit"), "dataset": previous.get("dataset"), **rec}
        for r in rec.get("rounds", []):
            if sha in (r.get("policy_sha256"), r.get("sha256")):
                return r
    raise SystemExit(f"--init file with sha256 {sha[:12]}… is neither a run directory nor in {out}")


def rounds(run: Path) -> list[dict]:
    """The run's round, preceded by the rounds of the policy it was warm-started from."""
    cfg = json.loads((run / "config.json").read_text())
    t = cfg["train"]
    lines = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    vals = [d for d in lines if "val_loss" in d]
    best = min(vals, key=lambda d: d["val_loss"])
    weights = t.get("data_weights") or [1.0] * (1 + len(t.get("more_data") or []))
    data = [t["data"], *(t.get("more_data") or [])]
    args = " ".join(f"--data {p}" for p in data)
    if t.get("data_weights"):
        args += " --data-weights " + ",".join(f"{w:g}" for w in weights)
    init = t.get("init")
    if init:
        args += f" --init {init}"
    if t.get("augment", "none") != "none":
        args += f" --augment {t['augment']}"
    if t.get("seed") is not None:
        args += f" --seed {t['seed']}"
    this = {
        "command": (f"madp train --model {t['model']} --preset {t['preset']} {args} --lr {t['lr']:g} "
                    f"--out {t['out']} --threads 1 --epochs {t['epochs']} --max-steps-per-epoch {t['max_steps_per_epoch']}"),
        "datasets": [dataset(p, w) for p, w in zip(data, weights)],
        "train_config": t,
        "num_parameters": cfg["num_parameters"],
        "steps": max(d.get("step", 0) for d in lines),
        "best_val_loss": best["val_loss"],
        "best_step": best["step"],
        "val_loss_by_epoch": [d["val_loss"] for d in vals],
        "policy_sha256": sha256(run / "checkpoints" / "best" / "policy.safetensors"),
    }
    if not init:
        return [this]
    ip = Path(init)
    run_dir = ip.parents[2] if len(ip.parents) > 2 else None
    if run_dir is not None and (run_dir / "config.json").exists() and (run_dir / "metrics.jsonl").exists():
        before = rounds(run_dir)
    else:
        before = [earlier_record(cfg["init"]["sha256"] if isinstance(cfg.get("init"), dict) else sha256(ip))]
    return [*before, this]


record = {
    "git_commit": subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True).stdout.strip(),
    # checkpoints not named on the command line keep their record (each names the expert dataset whose
    # training split's action statistics it normalises with: "dataset")
    "checkpoints": {name: {**rec, "dataset": rec.get("dataset", previous.get("dataset"))}
                    for name, rec in previous["checkpoints"].items()},
}
for run in map(Path, sys.argv[1:]):
    cfg = json.loads((run / "config.json").read_text())
    t = cfg["train"]
    expert = {"command": cfg["dataset"]["created_by"], "root": cfg["dataset"]["root"], "action_stats": cfg["action_stats"]}
    name = f"{t['model']}-{t['preset']}.safetensors"
    f = root / "madp" / "checkpoints" / name
    chain = rounds(run)
    if sha256(f) != chain[-1]["policy_sha256"]:
        raise SystemExit(f"{f} is not {run}/checkpoints/best/policy.safetensors: copy it there first")
    record["checkpoints"][name] = {"sha256": sha256(f), "bytes": f.stat().st_size, "dataset": expert, "rounds": chain}
out.write_text(json.dumps(record, indent=1) + "\n")
print(out)
