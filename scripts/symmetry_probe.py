"""How far the learned policies are from the world's symmetry, state by state (README, Exploration).

For each launch layout's first environments (the ``launch`` suite's scenarios), at t = 0 and after
100 expert steps, every image g of the state under the square world's 8 rotations and reflections is
built in the simulator (``Scenario.d4_image``, the expert stepping each image: the world is exactly
symmetric, tests/sim/test_launch.py). An equivariant policy acts on the image as the image of its
action: ``a(g x) = A_g a(x)``. Printed per layout, t and policy: the mean over robots and the 7
non-trivial images of ``|a(g x) - A_g a(x)| / mean |a(x)|``. For MADP (decentralized, the evaluation
default sampler) the initial noise of the image is the image of the noise (``A_g z``), and beside it
stands the same measure between two independent noise draws on one state (the spread a sample has
anyway). "Orbit drift": the swarm's mean velocity averaged over the 8 images of a state, which is
exactly zero for an equivariant policy (and for the expert): a preferred direction of the world.

    python scripts/symmetry_probe.py [--envs 6] [--out docs/results/symmetry_probe.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from madp.eval.suites import suite_envs
from madp.models.samplers import DEFAULT_SAMPLER, DEFAULT_SAMPLING_STEPS
from madp.policies import load, shipped_checkpoint
from madp.sim import ClairvoyantCVT, CoverageEnv
from madp.sim.launch import D4_SIZE, d4_matrix


def _tensors(env: CoverageEnv) -> tuple[torch.Tensor, torch.Tensor]:
    return torch.from_numpy(env.observations())[None], torch.from_numpy(env.positions_m.astype(np.float32))[None]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", type=int, default=6, help="environments per launch layout")
    p.add_argument("--out", type=Path, default=None, help="also write the table as JSON")
    args = p.parse_args()
    torch.set_num_threads(1)
    madp, _ = load(shipped_checkpoint("madp"), "madp")
    lpac, _ = load(shipped_checkpoint("lpac"), "lpac")

    def madp_act(o, pos, z):
        return madp.denormalize_actions(madp.sample_decentralized(o, pos, DEFAULT_SAMPLING_STEPS, 0.0,
                                                                  sampler=DEFAULT_SAMPLER, noise=z))[0]

    errors: dict[tuple, list[float]] = {}
    for spec in suite_envs("launch", args.envs):
        sc = spec.scenario()
        envs = [CoverageEnv(sc.d4_image(g)) for g in range(D4_SIZE)]
        expert = ClairvoyantCVT()
        for t in (0, 100):
            for _ in range(t):  # from the t = 0 state: 100 expert steps
                for e in envs:
                    e.step(expert(e))
            gen = torch.Generator().manual_seed(spec.index)
            z = torch.randn(1, sc.params.num_robots, 2, generator=gen)
            z2 = torch.randn(1, sc.params.num_robots, 2, generator=gen)
            with torch.no_grad():
                o, pos = _tensors(envs[0])
                base = {"lpac": lpac.denormalize_actions(lpac(o, pos))[0], "madp": madp_act(o, pos, z)}
                spread = madp_act(o, pos, z2)
                scale = {k: float(v.norm(dim=-1).mean()) for k, v in base.items()}
                errors.setdefault((spec.group, t, "madp", "noise"), []).append(
                    float((spread - base["madp"]).norm(dim=-1).mean()) / scale["madp"])
                orbit_mean = {k: v.mean(0) / D4_SIZE for k, v in base.items()}  # the swarm's mean velocity over the orbit
                for g in range(1, D4_SIZE):
                    a = torch.tensor(d4_matrix(g), dtype=torch.float32)
                    o, pos = _tensors(envs[g])
                    image = {"lpac": lpac.denormalize_actions(lpac(o, pos))[0], "madp": madp_act(o, pos, z @ a.T)}
                    for k in base:
                        err = float((image[k] - base[k] @ a.T).norm(dim=-1).mean()) / scale[k]
                        errors.setdefault((spec.group, t, k, "image"), []).append(err)
                        orbit_mean[k] = orbit_mean[k] + image[k].mean(0) / D4_SIZE
                for k, v in orbit_mean.items():  # zero for an equivariant policy: sum_g A_g v = 0
                    errors.setdefault((spec.group, t, k, "drift_x"), []).append(float(v[0]))
                    errors.setdefault((spec.group, t, k, "drift_y"), []).append(float(v[1]))
    rows = [{"launch": k[0], "t": k[1], "policy": k[2], "compared": k[3], "mean": float(np.mean(v)),
             "se": float(np.std(v, ddof=1) / np.sqrt(len(v))), "n": len(v)} for k, v in sorted(errors.items())]
    print(f"{'launch':<8}{'t':>5}  {'policy':<6}{'a(gx) vs A a(x)':>18}{'two noise draws':>18}"
          f"{'orbit drift x, y (m/s)':>28}")
    for launch in ("uniform", "square", "line"):
        for t in (0, 100):
            for pol in ("lpac", "madp"):
                img = next(r for r in rows if (r["launch"], r["t"], r["policy"], r["compared"]) == (launch, t, pol, "image"))
                noise = [r for r in rows if (r["launch"], r["t"], r["policy"], r["compared"]) == (launch, t, pol, "noise")]
                nz = f"{noise[0]['mean']:.3f} ± {noise[0]['se']:.3f}" if noise else "- (deterministic)"
                dx, dy = (next(r for r in rows if (r["launch"], r["t"], r["policy"], r["compared"]) == (launch, t, pol, c))
                          for c in ("drift_x", "drift_y"))
                drift = f"{dx['mean']:+.2f} ± {dx['se']:.2f}, {dy['mean']:+.2f} ± {dy['se']:.2f}"
                print(f"{launch:<8}{t:>5}  {pol:<6}{img['mean']:>11.3f} ± {img['se']:.3f}{nz:>18}{drift:>28}")
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
