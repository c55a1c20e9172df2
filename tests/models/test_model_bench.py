"""The model micro-benchmarks report numbers that mean what they say (speeds themselves are machine
dependent: only the timing-free relations are in the default run; the speed claim is ``slow``)."""

import pytest
import torch

from madp.models import MADP, lpac_config, madp_config
from madp.models.lpac import LPAC
from madp.models.bench import bench_infer, random_swarm


def test_infer_report_neighbourhoods():
    """The square launch puts everyone within r_c of everyone (M = N); the uniform one reports the
    neighbourhood sizes of the swarm it timed (recomputed here from distances)."""
    r = bench_infer("cpu", "decentralized", num_steps=2, num_robots=6, repeats=2, warmup=0, layout="square")
    assert r["max_neighbourhood"] == 6 and r["mean_neighbourhood"] == 6.0
    assert r["latency_min_s"] <= r["latency_s"] <= r["latency_max_s"]
    r = bench_infer("cpu", "centralized", num_steps=2, num_robots=12, repeats=1, warmup=0, seed=3)
    _, pos, _ = random_swarm(1, 12, generator=torch.Generator().manual_seed(3))
    sizes = (torch.cdist(pos[0].double(), pos[0].double()) < 256.0).sum(1)
    assert r["max_neighbourhood"] == int(sizes.max()) and r["mean_neighbourhood"] == pytest.approx(float(sizes.double().mean()))
    assert 1 <= r["max_neighbourhood"] < 12  # uniform over the world: not everyone sees everyone


@pytest.mark.slow
def test_dedupe_makes_a_fully_connected_swarm_several_times_cheaper():
    """docs/reports/2026-12-01-sampler-steps.md: with everyone in range all 32 neighbourhoods are the same robots, so
    dedupe computes one instead of 32 (measured ~6x faster on 1 thread). Timing: slow marker."""
    kw = dict(num_steps=10, num_robots=32, repeats=5, warmup=1, layout="square", sampler="ddim", threads=1)
    fast = bench_infer("cpu", "decentralized", dedupe=True, **kw)
    slow = bench_infer("cpu", "decentralized", dedupe=False, **kw)
    assert fast["latency_min_s"] * 3 < slow["latency_min_s"], (fast["latency_min_s"], slow["latency_min_s"])
