"""The ``value`` rule's learned map prior: its inputs and targets, the weights it gives unexplored
blocks, its examples and training into a policy file that carries it, and the one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors import safe_open

from madp.controllers import make_controller
from madp.errors import InputError, SettingError
from madp.models.map_prior import MapPrior, prior_inputs, prior_targets, prior_weights, window_masks
from madp.policies import SamplingSettings
from madp.policies.checkpoint import load_map_prior, load_policy
from madp.robot.choice import joint_copy
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.training.map_prior import collect, expectile_loss, train
from tests.test_reliability_errors import cli

SHIPPED = Path(__file__).resolve().parents[2] / "madp" / "checkpoints" / "madp-cpu.safetensors"


def test_inputs_and_targets_per_coarse_cell():
    g = 8  # two coarse cells of 4 blocks (4 m) per axis
    w = np.zeros((1, g, g))
    w[0, :4, :4] = 32.0  # 2 per m² in the first coarse cell
    unexplored = np.zeros((1, g, g), bool)
    unexplored[0, :4, :2] = True  # half of it unexplored
    inside = np.ones((1, g, g), bool)
    inside[0, 4:, 4:] = False  # the last coarse cell outside the world
    x = prior_inputs(w, unexplored, inside, 4)
    assert x.shape == (1, 3, 2, 2)
    assert x[0, 0, 0, 0] == pytest.approx(2.0) and x[0, 1, 0, 0] == pytest.approx(0.5)
    assert x[0, 2, 1, 1] == 0 and x[0, 1, 1, 1] == 0 and x[0, 0, 1, 1] == 0
    y = prior_targets(w, inside, 4)
    assert y[0, 0, 0] == pytest.approx(2.0) and y[0, 1, 1] == 0


def test_prior_weights_fill_only_unexplored_blocks_inside():
    torch.manual_seed(0)
    net = MapPrior().eval()
    rng = np.random.default_rng(0)
    w = rng.random((3, 64, 64))
    unexplored = rng.random((3, 64, 64)) < 0.5
    inside = window_masks(np.array([[-100.0, 0.0], [0.0, 0.0], [900.0, 900.0]]), 64, 4, 1024)
    out = prior_weights(net, w, unexplored, inside, 4)
    fill = unexplored & inside
    assert np.array_equal(out[~fill], w[~fill]) and (out[fill] > w[fill]).all()
    assert np.array_equal(prior_weights(net, w, np.zeros_like(unexplored), inside, 4), w)
    high = np.where(fill, 1e6, 0.0)  # a floor above every prediction: the floor
    np.testing.assert_array_equal(prior_weights(net, w, unexplored, inside, 4, high)[fill], w[fill] + 1e6)
    np.testing.assert_array_equal(prior_weights(net, w, unexplored, inside, 4, np.zeros_like(w)), out)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    d = tmp_path_factory.mktemp("prior")
    meta = collect(d / "ex.npz", 2, every=10, steps=21, batch=2, progress=False)
    scores = train(d / "ex.npz", SHIPPED, d / "policy.safetensors", epochs=2, batch=64, progress=False)
    return d, meta, scores


def test_collect_and_train_write_a_policy_file_that_carries_the_prior(trained):
    d, meta, scores = trained
    assert meta["examples"] == 2 * 3 * 32  # steps 0, 10 and 20 of two rollouts, every robot
    assert np.isfinite(scores["held_out_mse"]) and scores["held_out_examples"] == 3 * 32
    model, _ = load_policy(d / "policy.safetensors")
    shipped, _ = load_policy(SHIPPED)
    assert all(torch.equal(a, b) for a, b in zip(model.state_dict().values(), shipped.state_dict().values()))
    assert isinstance(load_map_prior(d / "policy.safetensors"), MapPrior)
    assert load_map_prior(SHIPPED) is None


def test_the_value_rule_acts_with_the_prior_and_refuses_a_file_without_one(trained):
    d, _, _ = trained
    sampling = SamplingSettings.of(select="value")
    ctrl = make_controller("madp", str(d / "policy.safetensors"), sampling=sampling)
    env = CoverageEnv(Scenario.random(3, SimParams()))
    u = ctrl(env)
    assert u.shape == (32, 2) and np.isfinite(u).all()
    with pytest.raises(SettingError, match="carries none"):
        make_controller("madp", str(SHIPPED), sampling=sampling)
    floor = make_controller("madp", str(d / "policy.safetensors"), sampling=SamplingSettings.of(select="value_explore"))
    assert np.isfinite(floor(CoverageEnv(Scenario.random(3, SimParams())))).all()
    joint = make_controller("madp", str(d / "policy.safetensors"), sampling=SamplingSettings.of(select="value_joint"))
    assert np.isfinite(joint(CoverageEnv(Scenario.random(3, SimParams())))).all()


def test_joint_copy_keeps_one_copy_per_neighbourhood():
    costs = np.array([[0.0, 5.0], [9.0, 1.0], [9.0, 1.0], [1.0, 0.0]])  # robots 0-2 one neighbourhood, 3 alone
    near = np.zeros((4, 4), dtype=bool)
    near[:3, :3] = True
    assert joint_copy(costs, near).tolist() == [1, 1, 1, 1]  # robot 0 gives up its own best for the pack's
    assert costs.argmin(1).tolist() == [0, 1, 1, 1]
    assert joint_copy(costs, np.zeros((4, 4), dtype=bool)).tolist() == [0, 1, 1, 1]  # alone: its own best
    assert joint_copy(np.zeros((2, 3)), np.ones((2, 2), dtype=bool)).tolist() == [0, 0]  # ties: the lowest copy


def test_bad_examples_files_are_one_line_errors(trained, tmp_path):
    d, _, _ = trained
    cut = tmp_path / "cut.npz"
    cut.write_bytes((d / "ex.npz").read_bytes()[:1000])
    with pytest.raises(InputError, match="cut.npz: not a map-prior examples file"):
        train(cut, SHIPPED, tmp_path / "p.safetensors", progress=False)
    code, err = cli("value", "train", "--data", tmp_path / "none.npz", "--out", tmp_path / "p.safetensors")
    assert code == 2 and "none.npz: not found" in err and "Traceback" not in err
    code, err = cli("value", "train", "--data", d / "ex.npz", "--out", d / "policy.safetensors")
    assert code == 2 and "exists" in err


def test_value_explore_joint_is_the_joint_choice_on_value_explores_map():
    """``value_explore_joint`` keeps, per robot, its action of the copy whose costs on ``value_explore``'s
    map (the prior with ``explore``'s floor), summed over the neighbours it holds, are least. With a
    prior that predicts nothing the floor is all there is, and it changes what robots keep."""
    from madp.models.map_prior import predictor
    from madp.policies.select import local_cell_costs, local_views, select_actions
    from madp.selection import RULES, weigh
    from madp.robot.choice import lone_steps

    prior = MapPrior().eval()
    with torch.no_grad():
        prior.head.bias.fill_(-30.0)  # softplus: about 1e-13 per m² everywhere
    env = CoverageEnv(Scenario.random(5, SimParams(num_robots=12, num_features=8), launch=(300.0, 300.0, 500.0, 500.0)))
    cands = np.random.default_rng(0).uniform(-3.0, 3.0, (6, 12, 2))
    per_robot = cands.transpose(1, 0, 2)
    views = weigh(RULES["value_explore"], env.maps, local_views(env), predictor(prior))
    costs = local_cell_costs(views, per_robot, env.params)
    lone, steps = lone_steps(views, env.params)
    pick = joint_copy(costs, env.neighbour_view()[0])
    want = np.where(lone[:, None], steps, np.take_along_axis(per_robot, pick[:, None, None], 1)[:, 0])
    np.testing.assert_array_equal(select_actions("value_explore_joint", env, cands, prior), want)
    assert not np.array_equal(want, select_actions("value_joint", env, cands, prior))  # the floor changes a choice


def test_expectile_loss_is_the_squared_error_at_one_half_and_optimistic_above():
    g = torch.Generator().manual_seed(0)
    y, w = torch.rand(64, 4, 4, generator=g), torch.rand(64, 4, 4, generator=g)
    pred = torch.rand(64, 4, 4, generator=g)
    assert torch.equal(expectile_loss(pred, y, w, 0.5), ((pred - y) ** 2 * w).sum() / w.sum())
    # the constant that minimises it: the weighted mean at 0.5, above the mean for τ > 0.5
    c = torch.linspace(0.0, 1.0, 1001)
    best = {tau: float(c[torch.stack([expectile_loss(torch.full_like(y, v), y, w, tau) for v in c]).argmin()])
            for tau in (0.5, 0.8)}
    mean = float((y * w).sum() / w.sum())
    assert abs(best[0.5] - mean) < 1e-3 and best[0.8] > mean + 0.05


def test_train_refuses_an_expectile_outside_the_open_unit_interval_and_records_the_one_it_fits(trained, tmp_path):
    d, _, scores = trained
    assert np.isfinite(scores["held_out_bias"]) and np.isfinite(scores["explore_mean_bias"])
    train(d / "ex.npz", SHIPPED, tmp_path / "e.safetensors", epochs=1, batch=64, expectile=0.8, progress=False)
    with safe_open(str(tmp_path / "e.safetensors"), framework="pt") as f:
        assert json.loads(f.metadata()["map_prior_training"])["expectile"] == 0.8
    with pytest.raises(SettingError, match="expectile"):
        train(d / "ex.npz", SHIPPED, tmp_path / "p.safetensors", expectile=1.0, progress=False)
    code, err = cli("value", "train", "--data", d / "ex.npz", "--out", tmp_path / "p.safetensors", "--expectile", "0")
    assert code == 2 and "expectile" in err and "Traceback" not in err
