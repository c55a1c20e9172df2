"""Shared fixtures: small episode sets and helpers for bit-exact comparison."""

from __future__ import annotations

import numpy as np
import pytest

from madp.data_schema import Episode, SampleBatch
from madp.data_schema.bench import synthetic_episodes

FIELDS = ("episode_id", "step", "scenario_seed", "actions", "positions", "observations")


def random_finite(rng: np.random.Generator, shape, dtype) -> np.ndarray:
    """Random bit patterns of ``dtype`` with every NaN/inf replaced: exercises subnormals, -0, extremes."""
    dt = np.dtype(dtype)
    bits = rng.integers(0, 2 ** (8 * dt.itemsize), size=shape, dtype=np.uint64).astype(f"<u{dt.itemsize}")
    x = bits.view(dt)
    x[~np.isfinite(x)] = dt.type(1.5)
    return x


def random_episodes(num_robots: int = 6, lengths=(5, 3, 4), seed: int = 7, with_extras: bool = True) -> list[Episode]:
    """Episodes of NaN-free random bits (every float16/float32 pattern is fair game)."""
    rng = np.random.default_rng(seed)
    eps = []
    for k, t in enumerate(lengths):
        extras = {}
        if with_extras:
            extras = {
                "world_map": rng.random((64, 64), dtype=np.float32),
                "goals": rng.uniform(0, 1024, (t, num_robots, 2)).astype(np.float32),
            }
        eps.append(
            Episode(
                episode_id=100 + 3 * k,
                scenario_seed=2**62 + k,
                actions=random_finite(rng, (t, num_robots, 2), "<f4"),
                positions=random_finite(rng, (t, num_robots, 2), "<f4"),
                observations=random_finite(rng, (t, num_robots, 4, 32, 32), "<f2"),
                steps=np.sort(rng.choice(10_000, size=t, replace=False)).astype(np.int64),
                **extras,
            )
        )
    return eps


def batch_of(episodes) -> SampleBatch:
    return SampleBatch.concat([e.to_batch() for e in episodes])


def assert_bit_equal(a: SampleBatch, b: SampleBatch) -> None:
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        assert x.shape == y.shape, name
        assert x.tobytes() == y.tobytes(), f"{name} differs"


@pytest.fixture(scope="session")
def rand_episodes() -> list[Episode]:
    return random_episodes()


@pytest.fixture(scope="session")
def real_episodes() -> list[Episode]:
    """Realistic synthetic data, N = 32, with world maps and goals."""
    return synthetic_episodes(40, num_robots=32, steps_per_episode=16, seed=3, world_size=128)


@pytest.fixture(params=["mcap", "parquet"])
def fmt(request) -> str:
    return request.param
