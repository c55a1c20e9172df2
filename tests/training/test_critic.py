"""The learned critic of MADP's joint copies: its labels (the true J of each copy), its inputs, the
copies' scores and choices, training and the ranking numbers, and the one-line errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from madp.errors import InputError, SettingError
from madp.models.critic import critic_env_select, critic_predictor, load_critic
from madp.policies.select import oracle_costs
from madp.robot.choice import local_views
from madp.robot.critic import (copy_scores, critic_choice, critic_inputs, critic_select, neighbour_counts,
                               own_cell_fraction)
from madp.sim import CoverageEnv, SimParams
from madp.sim.voronoi import coverage_cost
from madp.training.critic import collect, load_labels, load_many, split_envs, stored_neighbours, world_prefix
from madp.training.critic_fit import gain_share, predicted_scores, ranking, spearman, state_moves, train
from madp.training.map_prior import _scenario
from tests.test_reliability_errors import cli


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
    windows, near = critic_inputs(env.maps, local_views(env), env.params.comm_radius_m)
    assert np.array_equal(data["x"][0], windows.astype(np.float16))
    assert np.allclose(stored_neighbours(data)[0], near, atol=1e-6)


def test_inputs_from_a_robots_window_and_neighbours():
    env = CoverageEnv(_scenario(0, 0, SimParams()))
    views = local_views(env)
    x, near = critic_inputs(env.maps, views, env.params.comm_radius_m)
    assert x.shape == (32, 5, 16, 16) and x.dtype == np.float32
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


def test_the_critic_trains_saves_loads_and_selects(labels, tmp_path):
    d, _ = labels
    data, _ = load_labels(d / "labels.npz")
    torch.manual_seed(0)
    net = train(data, np.array([0]), tmp_path / "critic.safetensors", epochs=2, batch=2, log=lambda _: None)
    loaded = load_critic(tmp_path / "critic.safetensors")
    assert loaded.record["train_envs"] == [0] and loaded.record["states"] == 2
    x = torch.from_numpy(data["x"][0].astype(np.float32))
    near = torch.from_numpy(stored_neighbours(data)[0])
    with torch.no_grad():
        assert all(torch.equal(a, b) for a, b in zip(net(x, near), loaded(x, near)))
    scores = predicted_scores(loaded, data)
    assert scores.shape == (4, 32, 3) and np.isfinite(scores).all()
    env = CoverageEnv(_scenario(0, 1, SimParams()))
    views = local_views(env)
    cand = np.random.default_rng(0).normal(size=(3, 32, 2))
    kept = critic_select(cand, views, critic_inputs(env.maps, views, 256.0), critic_predictor(loaded),
                         env.neighbour_view()[0], env.params, "team")
    assert any(np.array_equal(kept, c) for c in cand)  # team-wide: one whole copy
    assert np.array_equal(critic_env_select(env, cand, loaded, "team"), kept)  # nobody is alone at the start
    per_robot = critic_env_select(env, cand, loaded, "robot")
    assert all(any(np.array_equal(per_robot[i], c[i]) for c in cand) for i in range(32))
    with pytest.raises(SettingError, match="candidates_mps"):
        critic_select(cand[:, :5], views, critic_inputs(env.maps, views, 256.0), critic_predictor(loaded),
                      env.neighbour_view()[0], env.params)


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
