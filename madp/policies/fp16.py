"""``python -m madp.policies.fp16 POLICY OUT [--part-mib 16]``: write a policy checkpoint in float16,
split into checksummed parts when it is larger than ``--part-mib`` (the file format:
:mod:`madp.policies.parts`). The converted file loads wherever a policy file does."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from safetensors import safe_open

from .checkpoint import load_policy
from .parts import MAX_PART_BYTES, write_fp16


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m madp.policies.fp16",
                                 description="Write a policy checkpoint in float16, split into parts if larger than --part-mib.")
    ap.add_argument("policy", type=Path, help="policy.safetensors to convert")
    ap.add_argument("out", type=Path, help="the float16 file to write (or its index OUT.parts.json and parts OUT.000, ...)")
    ap.add_argument("--part-mib", type=float, default=MAX_PART_BYTES / (1 << 20), help="largest part (MiB; default 16)")
    args = ap.parse_args(argv)
    try:
        model, _ = load_policy(args.policy)
        with safe_open(str(args.policy), framework="pt") as f:
            metadata = dict(f.metadata() or {})
        files = write_fp16(model, metadata, args.out, int(args.part_mib * (1 << 20)))
    except (ValueError, OSError) as e:
        print(f"madp: error: {e}", file=sys.stderr)
        return 2
    for p in files:
        print(f"{p}  {p.stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
