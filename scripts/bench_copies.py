"""K samples of one swarm state (issue 26's candidates): MADP's decentralized sampling with ``copies=K``
(CNN and encoder once per state, the decoder on K copies) against the same call on K repeated states
(what the policy did before), in one process: medians and their ratio.

    .venv/bin/python scripts/bench_copies.py [--threads 1] [--repeats 20] [--robots 32]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from madp.models import MADP, madp_config
from madp.models.bench import _timed, random_swarm


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--robots", type=int, default=32)
    ap.add_argument("--candidates", default="4,16")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    model = MADP(madp_config("cpu")).eval()
    obs, pos, _ = random_swarm(1, args.robots, generator=torch.Generator().manual_seed(0))
    print(f"| K | repeated states (ms) | copies=K (ms) | ratio |  (N = {args.robots}, {args.threads} thread(s), "
          f"DPM-Solver++ S = 3, median of {args.repeats})")
    print("|---|---|---|---|")
    for k in (int(x) for x in args.candidates.split(",")):
        noise = torch.randn(k, args.robots, 2, generator=torch.Generator().manual_seed(1))
        with torch.no_grad():
            rep = _timed(lambda: model.sample_decentralized(obs.repeat_interleave(k, 0), pos.repeat_interleave(k, 0),
                                                            3, noise=noise, sampler="dpm++"), 2, args.repeats, "cpu")
            once = _timed(lambda: model.sample_decentralized(obs, pos, 3, noise=noise, sampler="dpm++", copies=k),
                          2, args.repeats, "cpu")
        a, b = 1e3 * float(np.median(rep)), 1e3 * float(np.median(once))
        print(f"| {k} | {a:.1f} | {b:.1f} | {a / b:.2f}x |")


if __name__ == "__main__":
    main()
