"""The robot runtime: one control step against the PyTorch policy with the same noise (1e-4 m/s), in
a process where importing torch fails, and its d4 frame against madp.models.symmetry."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

from madp.export.swarm import OnnxMADPPolicy
from madp.models.symmetry import inverse_actions, transform_state
from madp.policies import MADPPolicy, SamplingSettings, load, noise_generator, shipped_checkpoint
from madp.robot.frame import frame_element, inverse_action, transform_observation, transform_points
from madp.sim import CoverageEnv, Scenario, SimParams
from tests.robot.robot_testutils import export_tiny


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny-export")
    export_tiny(out)
    return out


@pytest.mark.parametrize("frame", ["d4", "world"])
def test_control_steps_match_the_pytorch_policy(frame):
    """Every robot's action of the shipped policy through the exported files, with the same noise,
    within 1e-4 m/s of the PyTorch policy's (the default: the critic it carries, among K = 4), over 3
    steps of a packed swarm."""
    from madp.controllers import make_controller

    ship = shipped_checkpoint("madp")
    sampling = SamplingSettings(frame=frame)
    sc = Scenario.random(3, SimParams(num_robots=10, num_features=8), launch=(300.0, 300.0, 650.0, 650.0))
    env_t, env_o = CoverageEnv(sc), CoverageEnv(sc)
    torch_policy = make_controller("madp", str(ship), seed=3, sampling=sampling)
    onnx_policy = OnnxMADPPolicy(ship, sampling, seed=3)
    assert torch_policy.select == onnx_policy.runtime.rule == sampling.select
    g_t, g_o = noise_generator(3), noise_generator(3)
    for _ in range(3):
        a = torch_policy.act_batch([env_t], [g_t])[0]
        b = onnx_policy.act_batch([env_o], [g_o])[0]
        assert np.abs(a - b).max() <= 1e-4
        env_t.step(a)
        env_o.step(b)
    assert env_o.neighbours().sum() > 0  # neighbourhoods of several robots, not lone ones


@pytest.mark.parametrize("select", ["value", "value_explore", "value_joint", "value_explore_joint", "critic", "critic_hood"])
def test_learned_rules_through_the_export_match_the_pytorch_policy(tmp_path, select):
    """The rules that read a learned network (the ``value`` rules' map prior, the ``critic`` rules'
    critic) robot by robot, the network through its exported graph (and under a ``_joint`` rule the cost
    round), act within 1e-4 m/s of the PyTorch policy with the same noise over 3 steps of a packed
    swarm; the network (random here) changes what some robot keeps against ``explore``, and the cost
    round what it keeps against the same rule robot by robot."""
    from madp.models.critic import Critic
    from madp.models.map_prior import MapPrior
    from madp.policies.checkpoint import attach, load_learned
    from madp.selection import RULES

    torch.manual_seed(1)
    policy = tmp_path / "policy.safetensors"
    needs = RULES[select].needs
    net = (MapPrior() if needs == "map prior" else Critic()).eval()
    attach(shipped_checkpoint("madp"), policy, needs, net, net.config.to_dict(), {})
    sampling = SamplingSettings.of(select=select)
    sc = Scenario.random(3, SimParams(num_robots=10, num_features=8), launch=(300.0, 300.0, 650.0, 650.0))
    env_t, env_o = CoverageEnv(sc), CoverageEnv(sc)
    torch_policy = MADPPolicy(load(policy, "madp")[0], sampling=sampling, seed=3, network=load_learned(policy, needs))
    # the rule it is checked against: explore, and for a _joint rule its per-robot rule (no cost round)
    alone = {"value_joint": "value", "value_explore_joint": "value_explore", "critic_hood": "critic"}
    other = SamplingSettings.of(select=alone[select]) if RULES[select].joint else SamplingSettings.of(select="explore")
    explore = MADPPolicy(load(policy, "madp")[0], sampling=other, seed=3, network=load_learned(policy, needs))
    onnx_policy = OnnxMADPPolicy(policy, sampling, seed=3)
    assert onnx_policy.runtime.rule == select
    g_t, g_o, g_e = noise_generator(3), noise_generator(3), noise_generator(3)
    differs = False
    for _ in range(3):
        a = torch_policy.act_batch([env_t], [g_t])[0]
        b = onnx_policy.act_batch([env_o], [g_o])[0]
        assert np.abs(a - b).max() <= 1e-4
        differs |= bool(np.abs(explore.act_batch([env_t], [g_e])[0] - a).max() > 1e-3)
        env_t.step(a)
        env_o.step(b)
    assert differs


def test_runtime_runs_where_torch_cannot_be_imported(tiny_dir):
    code = textwrap.dedent(f"""
        import sys
        sys.modules["torch"] = None  # any import of torch now raises ImportError
        import numpy as np
        from madp.robot import RobotRuntime
        from madp.robot.frame import frame_element
        from madp.sim import CoverageEnv, Scenario, SimParams
        from madp.sim.network import Message
        from madp.robot.choice import explore_prior, local_views
        env = CoverageEnv(Scenario.random(0, SimParams(num_robots=4, num_features=4), launch=(400, 400, 500, 500)))
        rt = RobotRuntime({str(tiny_dir)!r})
        obs, pos, nbr = env.observations(), env.positions_m, env.neighbours()
        sent = [rt.message(i, 0, obs[i], pos[i], pos[nbr[i]], 7) for i in range(4)]
        views = explore_prior(env, local_views(env))
        row = type(views)(views.start_m[:1], views.offset_m[:1], views.weights[:1], views.origin_m[:1],
                          views.neighbours_m[:1], views.valid[:1])
        bad = Message(2, 0, np.array([np.nan, 1.0]), sent[2].token)
        res = rt.step(0, 0, obs[0], pos[0], sent[1:] + [bad], 7, view=row)
        assert np.isfinite(res.action_mps).all() and res.counts.non_finite == 1 and res.counts.accepted == 3
        assert "torch" not in {{m.split(".")[0] for m, v in sys.modules.items() if v is not None}}
        print("ok", res.action_mps)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("ok")


@pytest.mark.parametrize("g", range(8))
def test_frame_of_one_robot_is_the_swarms(g):
    gen = torch.Generator().manual_seed(g)
    obs, pos = torch.rand(3, 4, 32, 32, generator=gen), torch.rand(3, 2, generator=gen) * 1024
    o, x = transform_state(obs, pos, g, 1024.0)
    for i in range(3):
        assert np.array_equal(transform_observation(obs[i].numpy(), g), o[i].numpy())
    assert np.array_equal(transform_points(pos.numpy(), g, 1024.0), x.numpy())
    u = torch.randn(3, 2, dtype=torch.float64, generator=gen)
    assert np.allclose(inverse_action(u.numpy(), g), inverse_actions(u, g).numpy(), atol=0, rtol=0)
    assert 0 <= frame_element(5, g) < 8
