"""The learned critic of MADP's joint copies: its labels (the true J of each copy), its inputs, the
copies' scores and choices, training and the ranking numbers, and the one-line errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from madp.errors import InputError, SettingError
from madp.models.critic import CriticConfig, critic_predictor, load_critic
from madp.policies.checkpoint import shipped_checkpoint
from madp.policies.select import oracle_costs, select_actions
from madp.robot.choice import explore_prior, joint_copy, local_views, lone_steps
from madp.robot.critic import (copy_scores, critic_choice, critic_costs, critic_inputs, critic_view, displacements_m, neighbour_counts,
                               own_cell_fraction)
from madp.sim import CoverageEnv, SimParams
from madp.sim.voronoi import coverage_cost
from madp.training.critic import collect, load_labels, load_many, split_envs, stored_neighbours, world_prefix
from madp.training.critic_fit import gain_share, predicted_scores, ranking, spearman, state_moves, train
from madp.robot.prior import window_inputs
from madp.training.map_prior import _scenario
from tests.test_reliability_errors import cli


def without_learned(policy, out):
    """``policy``'s policy alone, written to ``out``: the tensors and metadata of its learned networks left out."""
    from safetensors import safe_open
    from safetensors.torch import save_file

    from madp.policies.checkpoint import LEARNED

    keys = tuple(LEARNED.values())
    with safe_open(str(policy), framework="pt") as f:
        tensors = {k: f.get_tensor(k) for k in f.keys() if not k.startswith(tuple(f"{key}." for key in keys))}
        metadata = {k: v for k, v in (f.metadata() or {}).items() if k not in keys and k.removesuffix("_training") not in keys}
    save_file(tensors, str(out), metadata=metadata)
    return out


@pytest.fixture(scope="module")
def labels(tmp_path_factory):
    d = tmp_path_factory.mktemp("critic")
    meta = collect(d / "labels.npz", 2, every=2, steps=3, copies=3, batch=2, progress=False)
    return d, meta


def test_labels_have_their_shapes_and_are_the_copies_true_j(labels):
    d, meta = labels
    data, stored = load_labels(d / "labels.npz")
    assert meta["states"] == stored["states"] == 4  # steps 0 and 2 of two rollouts
    s, k, n = 4, 3, SimParams().num_robots
    shapes = {"x": (s, n, 5, 16, 16), "actions_mps": (s, k, n, 2), "j_before": (s,), "j_after": (s, k),
              "position_m": (s, n, 2), "neighbours": (s, n, n), "mass": (s, n), "centroid_m": (s, n, 2),
              "explore_costs": (s, n, k), "env": (s,), "step": (s,)}
    assert {key: data[key].shape for key in shapes} == shapes
    assert list(data["step"]) == [0, 0, 2, 2] and list(data["env"]) == [0, 1, 0, 1]
    for i in range(s):  # the label is oracle_costs of the copies from the stored state, bit for bit
        env = CoverageEnv(_scenario(0, int(data["env"][i]), SimParams()))
        env.start_m, env.offset_m = data["start_m"][i], data["offset_m"][i]
        assert np.array_equal(oracle_costs(env, data["actions_mps"][i]), data["j_after"][i])
        assert data["j_before"][i] == coverage_cost(env.prefix, data["position_m"][i])
    assert np.isnan(data["value_costs"]).all()  # no map prior given
    env = CoverageEnv(_scenario(0, 0, SimParams()))  # state 0: the start of rollout 0, as the robots see it
    windows, near = critic_inputs(critic_view(env.maps, local_views(env)), env.params)
    assert np.array_equal(data["x"][0], windows.astype(np.float16))
    assert np.allclose(stored_neighbours(data)[0], near, atol=1e-6)


def test_inputs_from_a_robots_window_and_neighbours():
    env = CoverageEnv(_scenario(0, 0, SimParams()))
    views = local_views(env)
    x, near = critic_inputs(critic_view(env.maps, views), env.params)
    assert x.shape == (32, 5, 16, 16) and x.dtype == np.float32
    assert np.array_equal(x[:, :3], window_inputs(env.maps, views)[0])  # the map prior's input of the sensed map
    with pytest.raises(ValueError, match="unexplored"):
        critic_inputs(views, env.params)
    assert near.shape == (32, 16, 3) and np.array_equal(near[:, :, 2].sum(1), np.minimum(views.valid.sum(1), 16))
    assert (np.abs(near[:, :, :2]) <= 1.0).all()  # within r_c
    own = own_cell_fraction(views)
    assert ((own >= 0) & (own <= 1)).all()
    counts = neighbour_counts(views)
    inside = ((views.neighbours_m - views.origin_m[:, None] >= 0) & (views.neighbours_m - views.origin_m[:, None] < 256))
    assert np.array_equal(counts.sum((1, 2)), (views.valid & inside.all(-1)).sum(1))


def test_own_cell_and_neighbours_on_a_hand_made_window():
    from madp.robot.choice import LocalViews
    from madp.robot.critic import neighbour_features

    # a 32 m window (8 blocks of 4 m, 2 coarse cells of 16 m), the robot at (16, 16), a neighbour at
    # (24, 16): the bisector x = 20 leaves the robot the first coarse column and 1 of 4 blocks of the second
    views = LocalViews(np.array([[16.0, 16.0]]), np.zeros((1, 2)), np.zeros((1, 8, 8)), np.zeros((1, 2)),
                       np.array([[[24.0, 16.0], [500.0, 0.0]]]), np.array([[True, True]]))
    assert np.allclose(own_cell_fraction(views), [[[1.0, 1.0], [0.25, 0.25]]])
    assert np.array_equal(neighbour_counts(views), [[[0.0, 0.0], [0.0, 1.0]]])  # the far one is outside
    near = neighbour_features(np.array([[[10.0, 0.0], [-300.0, 0.0], [5.0, 5.0]]]), np.array([[True, False, True]]),
                              100.0)
    assert near.shape == (1, 16, 3)
    assert np.allclose(near[0, :3], [[0.05, 0.05, 1.0], [0.1, 0.0, 1.0], [0.0, 0.0, 0.0]]) and not near[0, 2:].any()


def test_scores_choices_and_ranking_numbers_on_a_hand_made_example():
    # M (|δ − d|² − |d|²): mass 2, centroid 1 m along x; a move of 1 m toward it gains 2, staying 0.
    s = copy_scores(np.array([2.0]), np.array([[1.0, 0.0]]), np.array([[[1.0, 0.0], [0.0, 0.0], [-1.0, 0.0]]]))
    assert np.allclose(s, [[-2.0, 0.0, 6.0]])
    scores = np.array([[0.0, 1.0], [1.0, 0.0], [0.0, 3.0]])
    near = np.array([[False, True, False], [True, False, False], [False, False, False]])
    assert list(critic_choice(scores, near, "robot")) == [0, 1, 0]
    assert list(critic_choice(scores, near, "neighbourhood")) == [0, 0, 0]  # robots 0, 1 tie: lowest k
    assert list(critic_choice(scores + [[0, -2], [0, 0], [0, 0]], near, "neighbourhood")) == [1, 1, 0]
    assert list(critic_choice(scores, near, "team")) == [0, 0, 0]
    assert np.allclose(spearman(np.array([[1.0, 2, 3], [3, 2, 1]]), np.array([[10.0, 20, 30], [10, 20, 30]])), [1, -1])
    per_state, pooled = gain_share(np.array([[1.0, 2, 3], [4, 4, 7]]), np.array([1.0, 6.0]))
    assert np.allclose(per_state, [1.0, -1.0]) and pooled == pytest.approx((1 - 1) / (1 + 1))


def test_scores_ranked_as_the_true_j_keep_all_of_oracles_gain(labels):
    d, _ = labels
    data, _ = load_labels(d / "labels.npz")
    data["moves"] = state_moves(data)
    # scores that rank exactly as the true J does keep all of oracle's gain
    scores = np.broadcast_to(data["j_after"][:, None, :], data["explore_costs"].shape) / 32
    prefixes = {e: world_prefix(0, e) for e in (0, 1)}
    r = ranking(data, np.ascontiguousarray(scores), prefixes)
    assert r["spearman_team"] == pytest.approx(1.0) and r["gain_share_team"] == pytest.approx(1.0)
    assert r["gain_share_robot"] == pytest.approx(1.0)  # every robot keeps oracle's copy


def test_the_critic_trains_into_a_policy_file_and_its_rules_choose_with_it(labels, tmp_path):
    from madp.controllers import make_controller
    from madp.policies import SamplingSettings
    from madp.policies.checkpoint import carried, load_learned, load_policy, shipped_checkpoint
    from madp.selection import RULES

    d, _ = labels
    data, _ = load_labels(d / "labels.npz")
    torch.manual_seed(0)
    out = tmp_path / "policy.safetensors"
    net = train(data, np.array([0]), out, epochs=2, batch=2, log=lambda _: None)
    loaded = load_critic(out)
    assert loaded.record["train_envs"] == [0] and loaded.record["states"] == 2
    x = torch.from_numpy(data["x"][0].astype(np.float32))
    near = torch.from_numpy(stored_neighbours(data)[0])
    with torch.no_grad():
        assert all(torch.equal(a, b) for a, b in zip(net(x, near), loaded(x, near)))
    # the file is the shipped policy, the critic beside it (in place of the one the shipped file carries)
    policy, shipped = load_policy(out)[0], load_policy(shipped_checkpoint("madp"))[0]
    assert all(torch.equal(a, b) for a, b in zip(policy.state_dict().values(), shipped.state_dict().values()))
    assert carried(shipped_checkpoint("madp")) == carried(out) == ("critic",)
    # a policy file without a critic (a fine-tuned policy, say): critic, the default, runs its fallback,
    # explore; critic_hood, which has none, is refused
    plain = without_learned(out, tmp_path / "plain.safetensors")
    assert carried(plain) == () and load_learned(plain, "critic") is None
    fallback = make_controller("madp", str(plain), sampling=SamplingSettings.of(select="critic", candidates=2))
    assert fallback.network is None and fallback.select == RULES["critic"].fallback == "explore"
    with pytest.raises(SettingError, match="carries none"):
        make_controller("madp", str(plain), sampling=SamplingSettings.of(select="critic_hood", candidates=2))
    assert isinstance(make_controller("madp", out, sampling=SamplingSettings.of(select="critic", candidates=2)).network,
                      type(loaded))
    # madp critic attach: the critic onto the plain file again, weights equal, where it came from recorded
    code, err = cli("critic", "attach", "--critic", out, "--policy", plain, "--out", tmp_path / "again.safetensors")
    assert code == 0, err
    again = load_critic(tmp_path / "again.safetensors")
    assert all(torch.equal(a, b) for a, b in zip(again.state_dict().values(), loaded.state_dict().values()))
    assert again.record["attached_from"]["path"] == str(out) and again.record["train_envs"] == [0]
    code, err = cli("critic", "attach", "--critic", plain, "--policy", plain, "--out", tmp_path / "none.safetensors")
    assert code != 0 and "not a critic file" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "none.safetensors").exists()
    scores = predicted_scores(loaded, data)
    assert scores.shape == (4, 32, 3) and np.isfinite(scores).all()

    # the rules: each robot's (or neighbourhood's) least predicted change of J from its sensed map
    env = CoverageEnv(_scenario(0, 1, SimParams()))
    views = local_views(env)
    cand = np.random.default_rng(0).normal(size=(3, 32, 2))
    per_robot = cand.transpose(1, 0, 2)
    mass, offset = critic_predictor(loaded)(*critic_inputs(critic_view(env.maps, views), env.params))
    own = copy_scores(mass, offset, displacements_m(views, per_robot, env.params))
    held = critic_view(env.maps, views)
    assert np.array_equal(held.weights, explore_prior(env, views).weights)  # a lone robot's step reads explore's map
    assert np.array_equal(critic_costs(held, per_robot, env.params, critic_predictor(loaded)), own)
    assert not lone_steps(views, env.params)[0].any()  # nobody is alone at the start
    best = np.take_along_axis(per_robot, own.argmin(1)[:, None, None], 1)[:, 0]
    assert np.array_equal(select_actions("critic", env, cand, loaded), best)
    hood = joint_copy(own, env.neighbour_view()[0])
    assert np.array_equal(select_actions("critic_hood", env, cand, loaded),
                          np.take_along_axis(per_robot, hood[:, None, None], 1)[:, 0])
    with pytest.raises(SettingError, match="critic"):
        select_actions("critic", env, cand)
    with pytest.raises(SettingError, match="candidates_mps"):
        critic_costs(held, per_robot[:5], env.params, critic_predictor(loaded))


def test_a_next_round_continues_from_a_trained_critic(labels, tmp_path):
    """``madp critic train --init F``: F's critic (configuration, mass unit, weights) is where training starts,
    and the record names it and every environment either round learned from (ranking leaves them out)."""
    d, _ = labels
    data, _ = load_labels(d / "labels.npz")
    first = tmp_path / "first.safetensors"
    train(data, np.array([0]), first, epochs=1, batch=2, log=lambda _: None)
    start = load_critic(first)
    start.config = CriticConfig(**{**start.config.to_dict(), "mass_unit": 123.0})  # not the new labels' mean
    # a zero learning rate leaves the weights where they started: the start is the init's, not fresh ones
    same = train(data, np.array([1]), tmp_path / "same.safetensors", epochs=1, batch=2, lr=1e-12, log=lambda _: None,
                 init=start)
    assert same.config.mass_unit == 123.0
    assert all(torch.allclose(a, b, atol=1e-6) for a, b in zip(same.state_dict().values(), start.state_dict().values()))
    code, err = cli("critic", "train", "--data", d / "labels.npz", "--held-out", "0.5", "--epochs", "1",
                    "--init", first, "--lr", "1e-3", "--out", tmp_path / "next.safetensors")
    assert code == 0, err
    nxt = load_critic(tmp_path / "next.safetensors")
    assert nxt.record["init"]["path"] == str(first) and nxt.record["init"]["train_envs"] == [0]
    assert nxt.record["train_envs"] == [0] and nxt.record["lr"] == 1e-3
    assert not all(torch.equal(a, b) for a, b in zip(nxt.state_dict().values(), load_critic(first).state_dict().values()))
    code, err = cli("critic", "train", "--data", d / "labels.npz", "--init", d / "labels.npz",
                    "--out", tmp_path / "bad.safetensors")
    assert code != 0 and "not a critic file" in err and len(err.strip().splitlines()) == 1


def test_rounds_from_different_drivers_load_as_one_but_not_other_settings(labels, tmp_path):
    d, _ = labels
    shipped = shipped_checkpoint("madp")
    collect(tmp_path / "next.npz", 1, every=2, steps=3, copies=3, first=2, policy=str(shipped), progress=False)
    data, meta = load_many([d / "labels.npz", tmp_path / "next.npz"])
    assert list(data["env"]) == [0, 1, 0, 1, 2, 2] and meta["num_envs"] == 3 and meta["states"] == 6
    assert [m["policy"] for m in meta["policies"]] == ["shipped", str(shipped)] and "policy" not in meta
    collect(tmp_path / "other.npz", 1, every=2, steps=3, copies=2, first=3, progress=False)
    with pytest.raises(InputError, match="other settings"):
        load_many([d / "labels.npz", tmp_path / "other.npz"])


def test_bad_input_gets_one_line_errors(labels, tmp_path):
    d, _ = labels
    with pytest.raises(InputError, match="not found"):
        load_labels(tmp_path / "missing.npz")
    (tmp_path / "foreign.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="not a critic labels file"):
        load_labels(tmp_path / "foreign.npz")
    with pytest.raises(InputError, match="share environments"):
        load_many([d / "labels.npz", d / "labels.npz"])
    with pytest.raises(InputError, match="not a critic file"):
        load_critic(tmp_path / "foreign.npz")
    with pytest.raises(SettingError, match="npz"):
        collect(tmp_path / "labels.json", 1, progress=False)
    with pytest.raises(SettingError, match="exists"):
        collect(d / "labels.npz", 1, progress=False)
    with pytest.raises(SettingError, match="held_out"):
        split_envs(np.array([0, 1]), 1.5)
    with pytest.raises(SettingError, match="scope"):
        critic_choice(np.zeros((2, 3)), np.zeros((2, 2), bool), "swarm")
    assert [list(e) for e in split_envs(np.array([0, 0, 1, 2, 3]), 0.25)] == [[0, 1, 2], [3]]
    assert [list(e) for e in split_envs(np.array([0, 0, 1]), 0.0)] == [[0, 1], []]
    code, err = cli("critic", "train", "--data", tmp_path / "missing.npz", "--out", tmp_path / "c.safetensors")
    assert code != 0 and "not found" in err and len(err.strip().splitlines()) == 1


def test_the_exported_critic_runs_without_torch_as_in_torch(labels, tmp_path):
    from madp.robot.critic import onnx_predictor

    d, _ = labels
    data, _ = load_labels(d / "labels.npz")
    train(data, np.array([0]), tmp_path / "critic.safetensors", epochs=1, batch=2, log=lambda _: None)
    code, _ = cli("critic", "export", "--critic", tmp_path / "critic.safetensors", "--out", tmp_path / "critic.onnx")
    assert code == 0
    x, near = data["x"][1].astype(np.float32), stored_neighbours(data)[1]
    mass, offset = onnx_predictor(tmp_path / "critic.onnx")(x, near)
    mass_t, offset_t = critic_predictor(load_critic(tmp_path / "critic.safetensors"))(x, near)
    assert np.allclose(mass, mass_t, rtol=1e-4, atol=1e-6) and np.allclose(offset, offset_t, atol=1e-3)
    with pytest.raises(InputError, match="not a loadable ONNX graph"):
        onnx_predictor(tmp_path / "missing.onnx")
