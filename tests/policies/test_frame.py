"""MADP acting in a random frame of the world's symmetry group (SamplingSettings(frame="d4")).

The contract: in frame g the model sees the state moved by g and its actions are moved back, so the
policy's action distribution (over frames) is equivariant to the world's rotations and reflections
whatever the model learned. Checked exactly: with the same noise, the action in frame g at the
image ``h x`` of a state equals ``A_h`` times the action in frame ``g h`` at ``x``.
"""

import numpy as np
import pytest
import torch

import madp.policies.madp as madp_policy
from madp.errors import SettingError
from madp.models import MADP
from madp.policies import MADPPolicy, SamplingSettings
from madp.sim.rules import clip_speed
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.launch import D4_SIZE, d4_matrix
from tests.conftest import one_torch_thread
from tests.models.models_testutils import tiny_madp_config


def _compose(g: int, h: int) -> int:
    """The element whose matrix is ``A_g A_h``."""
    target = d4_matrix(g) @ d4_matrix(h)
    return next(k for k in range(D4_SIZE) if np.allclose(d4_matrix(k), target))


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    with one_torch_thread():
        yield MADP(tiny_madp_config()).eval()


def _actions(policy: MADPPolicy, env: CoverageEnv, g: int, monkeypatch) -> np.ndarray:
    monkeypatch.setattr(madp_policy, "frame_element", lambda seed, step: g)
    return policy.sample(env, 1, generator=torch.Generator().manual_seed(7))[0]


def test_actions_in_a_frame_are_equivariant(model, monkeypatch):
    params = SimParams(num_robots=6, num_features=4)
    sc = Scenario.random(3, params)
    policy = MADPPolicy(model, "decentralized", SamplingSettings.of(frame="d4", select="none"))  # one sample;
    # the choice among samples: tests/policies/test_select.py
    here = {g: _actions(policy, CoverageEnv(sc), g, monkeypatch) for g in range(D4_SIZE)}
    assert np.linalg.norm(here[0] - here[5]) > 1e-3  # the tiny model is not equivariant by itself
    for h in range(1, D4_SIZE):
        env_h = CoverageEnv(sc.d4_image(h))
        for g in range(D4_SIZE):
            there = _actions(policy, env_h, g, monkeypatch)
            np.testing.assert_allclose(there, here[_compose(g, h)] @ d4_matrix(h).T, atol=2e-4)


def test_world_frame_is_the_model_unchanged(model):
    sc = Scenario.random(4, SimParams(num_robots=5, num_features=4))
    env = CoverageEnv(sc)
    plain = MADPPolicy(model, "decentralized", SamplingSettings.of(frame="world", select="none")).sample(env, 1, generator=torch.Generator().manual_seed(1))
    obs = torch.from_numpy(env.observations())[None]
    pos = torch.from_numpy(env.positions_m.astype(np.float32))[None]
    z = torch.randn(1, 5, 2, generator=torch.Generator().manual_seed(1))
    direct = model.denormalize_actions(model.sample_decentralized(obs, pos, noise=z)).double().numpy()[0]
    np.testing.assert_allclose(plain[0], clip_speed(direct, sc.params.max_speed_mps), atol=1e-5)


def test_frame_elements_depend_on_seed_and_step_and_cover_the_group():
    a = [madp_policy.frame_element(11, t) for t in range(800)]
    assert a == [madp_policy.frame_element(11, t) for t in range(800)]
    assert a != [madp_policy.frame_element(12, t) for t in range(800)]
    counts = np.bincount(a, minlength=D4_SIZE)
    assert counts.min() > 60 and counts.max() < 140  # uniform: 100 each, SD ~9.4


def test_unknown_frame_is_refused():
    with pytest.raises(SettingError, match="frame"):
        SamplingSettings(frame="rotated")
