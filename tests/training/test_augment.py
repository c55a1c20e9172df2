"""D4 symmetry augmentation: a transformed sample equals the sample of the transformed scenario."""

import numpy as np
import pytest
import torch

from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario
from madp.models.symmetry import D4_SIZE, d4_matrix, transform_sample


def expert_samples(scenario: Scenario, steps: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    env, expert = CoverageEnv(scenario), ClairvoyantCVT()
    out = []
    for _ in range(steps):
        u = expert(env)
        out.append((env.observations(), env.positions_m.copy(), u))
        env.step(u)
    return out


@pytest.fixture(scope="module")
def scenario():
    sc = Scenario.random(seed=11)
    return Scenario(sc.features, sc.robots_m[:12], sc.params.__class__(**{**sc.params.__dict__, "num_robots": 12}))


def test_group_elements_are_the_eight_signed_permutations():
    mats = {tuple(d4_matrix(g).astype(int).ravel()) for g in range(D4_SIZE)}
    assert len(mats) == 8 and (1, 0, 0, 1) in mats
    for g in range(D4_SIZE):
        a = d4_matrix(g)
        assert np.allclose(a @ a.T, np.eye(2))


@pytest.mark.parametrize("g", range(1, D4_SIZE))
def test_transformed_sample_equals_sample_of_transformed_scenario(scenario, g):
    """Fails if a channel is moved the wrong way, if the neighbour offsets keep their old sign or
    axis, or if positions/actions are not rotated with the maps (observations after a few expert
    steps, so the robots' sensed maps and the expert's actions take part too)."""
    moved = scenario.d4_image(g)
    for (o, x, u), (o2, x2, u2) in zip(expert_samples(scenario, 4), expert_samples(moved, 4)):
        to, tx, tu = transform_sample(torch.from_numpy(o), torch.from_numpy(x), torch.from_numpy(u), g,
                                      scenario.params.world_size)
        np.testing.assert_allclose(tx.numpy(), x2, atol=1e-6)
        np.testing.assert_allclose(tu.numpy(), u2, atol=1e-4)
        np.testing.assert_allclose(to.numpy(), o2, atol=1e-4)
        assert np.abs(o2[:, 1:3]).max() > 0.05  # the neighbour channels are not empty


def test_identity_and_a_batch_dimension():
    obs, pos, act = torch.rand(3, 5, 4, 32, 32), torch.rand(3, 5, 2) * 1024, torch.randn(3, 5, 2)
    same = transform_sample(obs, pos, act, 0)
    assert all(torch.equal(p, q) for p, q in zip(same, (obs, pos, act)))
    one = transform_sample(obs[1], pos[1], act[1], 5)
    many = transform_sample(obs, pos, act, 5)
    assert all(torch.equal(p[1], q) for p, q in zip(many, one))
    with pytest.raises(ValueError):
        transform_sample(obs, pos, act, 8)
