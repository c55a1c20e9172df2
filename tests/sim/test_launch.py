"""Training launch layouts and the world's symmetries (madp.sim.launch, Scenario.d4_image)."""

import numpy as np
import pytest

from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario, SimParams
from madp.sim.launch import D4_SIZE, TRAINING_LAUNCHES, d4_matrix, d4_points, draw_launch

W = 1024.0


@pytest.mark.parametrize("launch", TRAINING_LAUNCHES)
def test_launch_is_a_pure_function_of_the_rng_and_stays_in_the_world(launch):
    for seed in range(40):
        a = draw_launch(np.random.default_rng(seed), launch, 32, W)
        b = draw_launch(np.random.default_rng(seed), launch, 32, W)
        assert a.shape == (32, 2) and np.array_equal(a, b)
        assert a.min() >= 1e-4 and a.max() <= W - 1e-4


def test_packed_launches_are_packed_and_varied():
    """Packed starts leave most of the world empty (the swarm's bounding box is small on average, and
    many robots start within r_c of each other), and they are not one fixed rectangle: their centres
    and extents vary. Fails if ``packed`` falls back to uniform draws or to a single layout."""
    boxes, centres, close = [], [], []
    for seed in range(60):
        p = draw_launch(np.random.default_rng(seed), "packed", 32, W)
        boxes.append(np.prod(np.ptp(p, axis=0)) / W**2)
        centres.append(p.mean(axis=0))
        d = np.linalg.norm(p[:, None] - p[None], axis=-1)
        close.append((d < 256).mean())
    u = draw_launch(np.random.default_rng(0), "uniform", 32, W)
    assert np.median(boxes) < 0.35 < np.prod(np.ptp(u, axis=0)) / W**2
    assert np.mean(close) > 0.5
    assert np.std(np.array(centres), axis=0).min() > 100


def test_unknown_launch_is_refused():
    with pytest.raises(ValueError, match="launch"):
        draw_launch(np.random.default_rng(0), "ring", 4, W)


def test_d4_is_the_group_of_the_square():
    """Eight distinct isometries fixing the centre; closed under composition; every element has its
    inverse; points of the world stay in the world."""
    mats = [d4_matrix(g) for g in range(D4_SIZE)]
    keys = {tuple(m.astype(int).ravel()) for m in mats}
    assert len(keys) == 8
    for a in mats:
        for b in mats:
            assert tuple((a @ b).astype(int).ravel()) in keys
    pts = np.random.default_rng(1).uniform(0, W, (50, 2))
    for g in range(D4_SIZE):
        q = d4_points(pts, g, W)
        assert q.min() >= 0 and q.max() <= W
        np.testing.assert_allclose(np.linalg.norm(q - W / 2, axis=1), np.linalg.norm(pts - W / 2, axis=1))
        back = (q - W / 2) @ d4_matrix(g) + W / 2  # A^-1 = A^T
        np.testing.assert_allclose(back, pts, atol=1e-9)
    with pytest.raises(ValueError):
        d4_matrix(8)


@pytest.mark.parametrize("g", range(1, D4_SIZE))
def test_the_world_is_symmetric(g):
    """The image of a scenario has the same cost, and the expert's actions there are the images of
    its actions here, for 30 steps: the property that makes a rotated scenario worth the same."""
    sc = Scenario.random(3, SimParams(num_robots=8, num_features=8))
    a, b = CoverageEnv(sc), CoverageEnv(sc.d4_image(g))
    expert = ClairvoyantCVT()
    assert b.normalized_cost() == pytest.approx(a.normalized_cost(), abs=1e-12)
    for _ in range(30):
        ua, ub = expert(a), expert(b)
        np.testing.assert_allclose(ub, ua @ d4_matrix(g).T, atol=1e-6)
        a.step(ua)
        b.step(ub)
    assert b.normalized_cost() == pytest.approx(a.normalized_cost(), rel=1e-6)
    assert sc.d4_image(g).name == f"d4-{g}"
