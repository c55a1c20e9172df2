"""Action normalisation pinned to values, not only as a round trip: a round trip passes even when
``normalize_actions`` and ``denormalize_actions`` are swapped (the issue-17 mutation in
``models/action_stats.py``), which would train on ``u * std + mean`` and act on ``(u - mean) / std``."""

import numpy as np
import pytest
import torch

from madp.models import MADP, lpac_config
from madp.models.lpac import LPAC
from madp.policies.lpac import LPACPolicy
from madp.sim import CoverageEnv, Scenario, SimParams
from .models_testutils import tiny_madp_config

MEAN = torch.tensor([0.5, -0.25])
STD = torch.tensor([2.0, 4.0])


@pytest.fixture(params=["madp", "lpac"])
def model(request):
    torch.manual_seed(0)
    m = MADP(tiny_madp_config()) if request.param == "madp" else LPAC(lpac_config("cpu", gnn_hidden=8))
    m.set_action_stats(MEAN, STD)
    return m.eval()


def test_normalize_is_minus_mean_over_std(model):
    """normalize(mean) = 0, normalize(mean + std) = 1, normalize(mean - 2 std) = -2, per action dim;
    denormalize is the inverse map. Fails if the two are swapped or a dim's statistics are mixed up."""
    u = torch.stack([MEAN, MEAN + STD, MEAN - 2 * STD])  # [3, 2] m/s
    assert torch.equal(model.normalize_actions(u), torch.tensor([[0.0, 0.0], [1.0, 1.0], [-2.0, -2.0]]))
    z = torch.tensor([[0.0, 0.0], [1.0, 1.0], [-2.0, 0.5]])
    assert torch.equal(model.denormalize_actions(z), torch.stack([MEAN, MEAN + STD, MEAN + torch.tensor([-4.0, 2.0])]))
    # broadcast over leading dims [B, N, 2]
    assert model.normalize_actions(u.expand(4, 3, 2)).shape == (4, 3, 2)
    # the statistics are buffers: they travel in every checkpoint
    sd = model.state_dict()
    assert torch.equal(sd["action_mean"], MEAN) and torch.equal(sd["action_std"], STD)


def test_policy_outputs_denormalised_actions_in_metres_per_second():
    """The controller returns mean + std * (the network's normalised output), clipped to u_max: fails
    if the policy normalises instead of denormalising, or forgets the statistics."""
    torch.manual_seed(0)
    model = LPAC(lpac_config("cpu", gnn_hidden=8)).eval()
    model.set_action_stats(torch.tensor([0.3, -0.1]), torch.tensor([0.01, 0.02]))  # keeps |u| below u_max
    sc = Scenario.random(5, SimParams(world_size=256, num_robots=4, num_features=3))
    env = CoverageEnv(sc)
    with torch.no_grad():
        u_norm = model(torch.from_numpy(env.observations())[None],
                       torch.from_numpy(env.positions_m.astype(np.float32))[None])[0].double().numpy()
    u = LPACPolicy(model)(env)
    assert np.abs(u).max() < sc.params.max_speed_mps
    np.testing.assert_allclose(u, np.array([0.3, -0.1]) + np.array([0.01, 0.02]) * u_norm, rtol=1e-5, atol=1e-7)


def test_statistics_keep_the_models_precision():
    """Statistics given as python floats (as read from a checkpoint's JSON metadata) are stored at
    the buffers' own precision: fails if they pass through float32 on the way into a float64 model."""
    m = MADP(tiny_madp_config()).double()
    m.set_action_stats([0.1, -0.2], [2.1, 1.3])
    assert m.action_mean.dtype == torch.float64
    assert m.action_mean.tolist() == [0.1, -0.2] and m.action_std.tolist() == [2.1, 1.3]
