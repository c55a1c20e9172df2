"""Choosing among MADP's samples (madp/policies/select.py, the chooser of madp/selection.py).

The contracts: the oracle keeps the joint sample of lowest true J after the step; a rule on the robot's
own map sees only that map and its neighbours within r_c; K = 1 with select none is MADP's sampling
unchanged; bad settings are refused in one line.
"""

import copy

import numpy as np
import pytest
import torch

import madp.policies.madp as madp_policy
import madp.policies.select as select_mod
import madp.selection as selection
from madp.errors import SettingError
from madp.models import MADP
from madp.policies import MADPPolicy, SamplingSettings, noise_generator
from madp.policies.select import explore_prior, local_cell_costs, local_views, oracle_costs, select_actions
from madp.robot.choice import joint_copy, lone_steps
from madp.selection import RULES, choose
from madp.sim.rules import clip_speed
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.robot_maps import EXPLORED_BLOCK_M
from tests.conftest import one_torch_thread
from tests.models.models_testutils import tiny_madp_config
from tests.test_reliability_errors import assert_one_line, cli

K = 4


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    with one_torch_thread():
        m = MADP(tiny_madp_config())
        m.set_action_stats(torch.zeros(2), torch.full((2,), 2.0))  # actions of a few m/s, so the candidates differ
        yield m.eval()


def _scenario(robots, params=None) -> Scenario:
    """Importance around robot 0 (at 300, 300) and elsewhere; robots at ``robots``."""
    robots = np.asarray(robots, dtype=np.float64)
    feats = np.array([[320.0, 310.0, 40.0, 1.0], [270.0, 350.0, 30.0, 0.7], [650.0, 700.0, 50.0, 0.9]])
    return Scenario(feats, robots, params or SimParams(num_robots=len(robots), num_features=len(feats)), seed=5)


#: Robot 0 at (300, 300); robot 1 its neighbour (< r_c = 256 m); robots 2-4 beyond r_c of robot 0.
ROBOTS = [[300.0, 300.0], [360.0, 330.0], [700.0, 700.0], [900.0, 200.0], [200.0, 800.0]]


def _candidates(seed: int, n: int) -> np.ndarray:
    """[K, N, 2] m/s, speeds up to u_max."""
    return np.random.default_rng(seed).uniform(-3.5, 3.5, (K, n, 2))


class Capture:
    """Wraps :func:`select_actions` to keep what the policy chose among."""

    def __init__(self, monkeypatch):
        self.calls = []
        monkeypatch.setattr(madp_policy, "select_actions", self)

    def __call__(self, select, env, candidates, network=None):
        chosen = select_actions(select, env, candidates, network)
        self.calls.append((candidates.copy(), chosen))
        return chosen


def test_oracle_keeps_the_joint_sample_of_lowest_true_cost_after_the_step(model, monkeypatch):
    env = CoverageEnv(Scenario.random(3, SimParams(num_robots=6, num_features=4)))
    before = env.positions_m.copy()
    seen = Capture(monkeypatch)
    policy = MADPPolicy(model, "decentralized", SamplingSettings(select="oracle", candidates=K))
    u = policy.act_batch([env], [noise_generator(9)])[0]
    (cands, chosen), = seen.calls
    assert cands.shape == (K, 6, 2) and np.abs(cands[1:] - cands[0]).max() > 1e-3  # K different joint samples
    direct = []
    for k in range(K):  # the true J after really stepping a copy of the environment
        e = copy.deepcopy(env)
        e.step(cands[k])
        direct.append(e.cost())
    np.testing.assert_array_equal(oracle_costs(env, cands), direct)  # the env's own motion rule, bit for bit
    best = int(np.argmin(direct))
    assert len(set(direct)) == K
    np.testing.assert_array_equal(u, cands[best])
    np.testing.assert_array_equal(env.positions_m, before)  # the oracle stepped copies only


def test_the_local_cell_cost_is_what_the_formula_says():
    """One robot, checked point by point on the coarse grid (a loop here, vectorised in the code)."""
    env = CoverageEnv(_scenario(ROBOTS))
    views = local_views(env)
    u = _candidates(1, 5).transpose(1, 0, 2)
    got = local_cell_costs(views, u, env.params)
    grid = select_mod.GRID_M
    own = env.maps.robot_map(0).astype(np.float64)
    cx, cy = env.cells()[0]
    total = np.zeros(K)
    for k in range(K):
        y = env.positions_m[0] + u[0, k] * env.params.dt_s  # |u| <= u_max and far from the border: no clipping
        for a in range(0, 256, grid):
            for b in range(0, 256, grid):
                x0, y0 = cx - 128 + a, cy - 128 + b
                if not (0 <= x0 < 1024 and 0 <= y0 < 1024):
                    continue
                q = np.array([x0 + grid / 2, y0 + grid / 2])
                mass = own[x0:x0 + grid, y0:y0 + grid].sum()
                d = ((q - y) ** 2).sum()
                if d <= ((q - env.positions_m[1]) ** 2).sum():  # robot 1 is robot 0's only neighbour
                    total[k] += mass * d
    np.testing.assert_allclose(got[0], total, rtol=1e-9)
    assert np.ptp(got[0]) > 0


def test_a_robots_choice_on_its_own_map_reads_only_what_it_knows():
    """Robot 0's choice does not change when the world changes outside what it sensed or a robot
    beyond its r_c moves; it does when a neighbour moves or its own sensed map changes."""
    base = CoverageEnv(_scenario(ROBOTS))
    cands = _candidates(2, 5)
    r0 = lambda env: local_cell_costs(local_views(env), cands.transpose(1, 0, 2), env.params)[0]  # noqa: E731
    choice0 = lambda env: choose(RULES["explore"], cands.transpose(1, 0, 2), local_views(env), env.params)[0][0]  # noqa: E731

    sensed = base.maps.robot_map(0) > 0
    assert sensed.sum() > 1000  # it has seen part of a feature
    world = base.world_map.copy()
    world[~sensed] += 0.3  # everything robot 0 has not sensed, its local window included
    unseen = CoverageEnv(_scenario(ROBOTS), world_map=world)
    far = [*ROBOTS[:2], [600.0, 500.0], *ROBOTS[3:]]  # robot 2 moves, still 360 m from robot 0
    moved_far = CoverageEnv(_scenario(far))
    assert np.linalg.norm(np.subtract(far[2], ROBOTS[0])) > base.params.comm_radius_m
    for other in (unseen, moved_far):
        np.testing.assert_array_equal(r0(other), r0(base))
        np.testing.assert_array_equal(choice0(other), choice0(base))
    assert oracle_costs(unseen, cands)[0] != oracle_costs(base, cands)[0]  # the true J did change

    near = [ROBOTS[0], [330.0, 290.0], *ROBOTS[2:]]  # the neighbour moves
    assert np.abs(r0(CoverageEnv(_scenario(near))) - r0(base)).max() > 1e-6 * r0(base).max()
    seen_world = base.world_map.copy()
    seen_world[sensed] *= 0.5
    assert np.abs(r0(CoverageEnv(_scenario(ROBOTS), world_map=seen_world)) - r0(base)).max() > 1e-6 * r0(base).max()


def test_oracle_cell_is_the_cell_rule_on_the_true_map():
    """``oracle_cell`` reads the world map in each robot's window: it sees importance the robot has
    not sensed (which ``cell`` does not), and equals ``cell`` where the robot has sensed its window."""
    base = CoverageEnv(_scenario(ROBOTS))
    cands = _candidates(2, 5)
    views = local_views(base, true_map=True)
    cx, cy = base.cells()[0]
    world = base.world_map.astype(np.float64)
    g = select_mod.GRID_M
    np.testing.assert_allclose(views.weights[0, 1, 2], world[cx - 128 + g:cx - 128 + 2 * g, cy - 128 + 2 * g:cy - 128 + 3 * g].sum(),
                               rtol=1e-6)
    sensed = base.maps.robot_map(0) > 0
    changed = base.world_map.copy()
    changed[~sensed] += 0.3
    other = CoverageEnv(_scenario(ROBOTS), world_map=changed)
    r0 = lambda env, true: local_cell_costs(local_views(env, true), cands.transpose(1, 0, 2), env.params)[0]  # noqa: E731
    np.testing.assert_array_equal(r0(other, False), r0(base, False))
    assert np.abs(r0(other, True) - r0(base, True)).min() > 0  # it sees the unsensed change
    full = CoverageEnv(_scenario(ROBOTS))
    full.maps.maps_padded[:] = full.maps.world_padded  # every robot has sensed the whole world
    full.maps.seen_lo[:], full.maps.seen_hi[:] = 0, full.maps.maps_padded.shape[1]  # (its sensed box)
    np.testing.assert_array_equal(r0(full, True), r0(full, False))
    lone, steps = lone_steps(views, base.params)  # a robot that hears no one takes its own step
    np.testing.assert_array_equal(select_actions("oracle_cell", base, cands),
                                  np.where(lone[:, None], steps, np.take_along_axis(cands.transpose(1, 0, 2), local_cell_costs(
                                      views, cands.transpose(1, 0, 2), base.params).argmin(1)[:, None, None], 1)[:, 0]))


def test_the_explored_map_holds_the_blocks_a_robots_sensor_covered():
    env = CoverageEnv(_scenario(ROBOTS))
    pad, b = env.maps.pad, EXPLORED_BLOCK_M
    (cx, cy) = env.cells()[0]  # (300, 300): sensor cells 268 .. 331 per axis
    x = env.maps.explored[0].copy()
    covered = np.argwhere(x)
    lo, hi = -(-(np.array([cx, cy]) - 32 + pad) // b), (np.array([cx, cy]) + 32 + pad) // b
    assert (covered.min(0) == lo).all() and (covered.max(0) == hi - 1).all() and x.sum() == np.prod(hi - lo)
    env.step(np.tile([[5.0, 0.0]], (len(ROBOTS), 1)))  # 1 m to +x: one more column of cells, not of blocks
    env.step(np.tile([[5.0, 0.0]], (len(ROBOTS), 1)))
    env.step(np.tile([[5.0, 0.0]], (len(ROBOTS), 1)))
    env.step(np.tile([[5.0, 0.0]], (len(ROBOTS), 1)))  # 4 m: one more column of blocks
    assert env.maps.explored[0].sum() == x.sum() + (hi - lo)[1] and env.maps.explored[0][x].all()
    assert env.maps.explored[1:].sum(axis=(1, 2)).min() > 0 and not env.maps.explored[1][x & ~env.maps.explored[1]].any()


def test_explore_counts_unexplored_blocks_at_the_mean_of_explored_ones():
    env = CoverageEnv(_scenario(ROBOTS))
    views = local_views(env)
    prior = explore_prior(env, views)
    added = prior.weights - views.weights
    assert (added >= 0).all()
    for r in range(len(ROBOTS)):
        got = np.unique(np.round(added[r][added[r] > 0], 9))
        assert len(got) == 1  # one prior mass per robot, on its unexplored blocks inside the world
    # robot 0 sensed importance: the prior is the mean mass of its explored blocks
    explored_blocks = (added[0] == 0) & (views.weights[0] > 0)
    assert np.unique(np.round(added[0][added[0] > 0], 9))[0] > 0 and explored_blocks.any()
    # a robot that has sensed nothing moves toward the unexplored part of its cell: from a corner of
    # the world, into it (with a neighbour, it chooses among its samples; alone, it steps there itself)
    corner = CoverageEnv(_scenario([[30.0, 30.0], [200.0, 200.0]]))
    cands = np.zeros((2, 2, 2))
    cands[0, 0], cands[1, 0] = [-3.0, -3.0], [3.0, 3.0]  # out of the world / into it
    assert local_views(corner).weights[0].sum() == 0
    np.testing.assert_array_equal(select_actions("explore", corner, cands)[0], [3.0, 3.0])
    alone = select_actions("explore", CoverageEnv(_scenario([[30.0, 30.0], [900.0, 900.0]])), cands)[0]
    assert alone[0] > 0 and np.isclose(alone[0], alone[1])


def test_explore_prior_is_on_exactly_the_blocks_not_explored_in_every_cell():
    """The prior is added to exactly the window blocks inside the world with a cell outside the
    robot's explored map, checked cell by cell on robots whose window corners are on and off the 4 m
    explored grid (a block read at its centre cell alone misses the ones whose other cells straddle)."""
    rng = np.random.default_rng(4)
    env = CoverageEnv(_scenario(ROBOTS))
    for _ in range(7):
        env.step(rng.normal(scale=2.5, size=(len(ROBOTS), 2)))
    views = local_views(env)
    added = explore_prior(env, views).weights - views.weights
    pad, w, g = env.maps.pad, env.params.world_size, views.weights.shape[1]
    corner = views.origin_m.astype(np.int64) + pad
    assert len(set((corner % EXPLORED_BLOCK_M).ravel().tolist())) > 1  # on and off the explored grid
    for r in range(len(ROBOTS)):
        cells = corner[r][:, None] + np.arange(g * 4)  # [2, 4G] padded cells of the window, per axis
        known = env.maps.explored[r][np.ix_(cells[0] // EXPLORED_BLOCK_M, cells[1] // EXPLORED_BLOCK_M)]
        all_known = known.reshape(g, 4, g, 4).all((1, 3))
        inside = ((cells >= pad) & (cells < pad + w)).reshape(2, g, 4).all(2)
        np.testing.assert_array_equal(added[r] > 0, ~all_known & inside[0][:, None] & inside[1][None, :])


@pytest.mark.parametrize("mode", ["decentralized", "centralized"])
def test_one_candidate_without_selection_is_the_sampling_unchanged(model, mode):
    """K = 1, select none, the world frame: the model's own sample with the generator's first draw, bit for bit."""
    env = CoverageEnv(Scenario.random(4, SimParams(num_robots=5, num_features=4)))
    policy = MADPPolicy(model, mode, SamplingSettings(select="none", candidates=1, frame="world"))
    fn = model.sample_decentralized if mode == "decentralized" else model.sample
    obs = torch.from_numpy(env.observations())[None]
    pos = torch.from_numpy(env.positions_m.astype(np.float32))[None]
    z = torch.randn(1, 5, 2, generator=noise_generator(11))
    with torch.no_grad():
        direct = model.denormalize_actions(fn(obs, pos, 3, 0.0, sampler="dpm++", noise=z)).double().numpy()[0]
    expected = clip_speed(direct, env.params.max_speed_mps)
    np.testing.assert_array_equal(policy.act_batch([env], [noise_generator(11)])[0], expected)
    np.testing.assert_array_equal(policy.sample(env, 1, noise_generator(11))[0], expected)


@pytest.mark.parametrize("select,candidates,setting", [
    ("best", 4, "select"), ("explore", 0, "candidates"), ("none", -1, "candidates"), ("value", 2.5, "candidates"),
    ("oracle", 1, "select/candidates"), ("none", 4, "select/candidates"),
])
def test_bad_selection_settings_are_refused(select, candidates, setting):
    with pytest.raises(SettingError) as e:
        SamplingSettings(select=select, candidates=candidates)
    assert e.value.setting == setting and "\n" not in str(e.value)


def test_oracle_joint_is_the_joint_choice_on_the_true_map():
    """``oracle_joint`` keeps, for each robot, its action of the copy whose cell costs on the true map,
    summed over the robot and the neighbours it holds, are least (the bound for ``value_joint``); a
    robot that hears no one takes its own step."""
    base = CoverageEnv(_scenario(ROBOTS))
    cands = _candidates(2, 5)
    views = local_views(base, true_map=True)
    per_robot = cands.transpose(1, 0, 2)
    copy_of = joint_copy(local_cell_costs(views, per_robot, base.params), base.neighbour_view()[0])
    lone, steps = lone_steps(views, base.params)
    want = np.where(lone[:, None], steps, np.take_along_axis(per_robot, copy_of[:, None, None], 1)[:, 0])
    np.testing.assert_array_equal(select_actions("oracle_joint", base, cands), want)
    own_best = local_cell_costs(views, per_robot, base.params).argmin(1)
    assert (copy_of != own_best)[~lone].any()  # some robot gives up its own best for its neighbourhood's


@pytest.mark.parametrize("args,line", [
    (["eval", "--select", "oracle", "--candidates", "1"], "madp: error: --select/--candidates: select oracle chooses among several samples "
                                     "per robot: expected candidates > 1, got 1"),
    (["eval", "--candidates", "0", "--select", "explore"], "madp: error: --candidates: expected a whole number of "
                                                       "samples per robot >= 1, got 0"),
    (["eval", "--select", "none", "--candidates", "3"], "madp: error: --select/--candidates: 3 candidates per robot need a rule to choose "
                                    "among them (explore, value, value_explore, value_joint, value_explore_joint, critic, critic_hood, oracle, oracle_hood, oracle_cell, oracle_joint), got select none"),
    (["eval", "--select", "vote", "--candidates", "3"], "madp: error: --select: expected one of none, explore, value, "
                                                        "value_explore, value_joint, value_explore_joint, critic, critic_hood, oracle, oracle_hood, oracle_cell, "
                                                        "oracle_joint, got 'vote'"),
])
def test_bad_selection_flags_are_one_line(tmp_path, args, line):
    """(A rule named alone takes its default K: ``SamplingSettings.of``, tested below.)"""
    assert assert_one_line(*cli(*args, "--out", tmp_path / "o")) == line


def test_a_rule_named_alone_takes_its_default_number_of_candidates():
    assert SamplingSettings.of(select="explore").candidates == selection.DEFAULT_CANDIDATES > 1
    assert SamplingSettings.of(select="none").candidates == 1
    assert SamplingSettings.of(select="oracle", candidates=16).candidates == 16
    default = SamplingSettings.of()
    assert (default.select, default.candidates) == (SamplingSettings().select, SamplingSettings().candidates)
    assert default.select == selection.DEFAULT_RULE


def test_rollout_refuses_bad_selection_flags_in_one_line(tmp_path):
    sc = tmp_path / "s.json"
    sc.write_text('{"features": [], "robots": [[1, 1]]}')
    code, err = cli("rollout", "--scenario", sc, "--controller", "madp", "--select", "explore", "--candidates", "1")
    assert_one_line(code, err, "--select/--candidates")


def _equivariance_misses(model, monkeypatch, select: str, seeds: tuple[int, ...]) -> tuple[int, int]:
    """Robots whose action at the image ``h x`` of a state in frame g is not ``A_h`` times their
    action at ``x`` in frame ``g h`` (same noise; tests/policies/test_frame.py), over the 7 × 8 (h, g)
    pairs and ``seeds`` scenarios of 6 robots: (misses, robots compared)."""
    from madp.sim.launch import D4_SIZE, d4_matrix
    from tests.policies.test_frame import _actions, _compose

    policy = MADPPolicy(model, "decentralized", SamplingSettings.of(select=select, candidates=3))
    misses = total = 0
    for seed in seeds:
        sc = Scenario.random(seed, SimParams(num_robots=6, num_features=4))
        here = {g: _actions(policy, CoverageEnv(sc), g, monkeypatch) for g in range(D4_SIZE)}
        for h in range(1, D4_SIZE):
            env_h = CoverageEnv(sc.d4_image(h))
            for g in range(D4_SIZE):
                there = _actions(policy, env_h, g, monkeypatch)
                gap = np.abs(there - here[_compose(g, h)] @ d4_matrix(h).T).max(1)
                misses, total = misses + int((gap > 2e-4).sum()), total + len(gap)
    return misses, total


@pytest.mark.parametrize("select,seeds", [("oracle_cell", (0,)), ("explore", (0, 1, 2))])
def test_choosing_among_samples_keeps_the_policy_equivariant(model, monkeypatch, select, seeds):
    """The robot's window blocks and its candidates move with the world's symmetry, so these rules
    choose the image of the same candidate: exactly equivariant, as one sample is. For ``explore`` its
    prior's rule (a window block is explored when every cell of it is, read at its four corners) is
    what the symmetries keep; read at one cell per block, 8 of these 1008 choices differed."""
    assert _equivariance_misses(model, monkeypatch, select, seeds=seeds) == (0, 6 * 56 * len(seeds))


def test_oracle_hood_keeps_each_neighbourhoods_copy_of_least_true_cell_cost():
    """``oracle_hood``: each robot's true whole-cell costs sum to the copy's true J; with every robot in
    one neighbourhood it keeps ``oracle``'s joint sample; a robot with no neighbour keeps the copy of
    least true cost of its own cell; its neighbour pair keeps the copy of least summed cost."""
    cands = _candidates(11, len(ROBOTS))
    env = CoverageEnv(_scenario(ROBOTS))
    cell = select_mod.oracle_cell_costs(env, cands)  # [N, K]
    np.testing.assert_allclose(cell.sum(0), oracle_costs(env, cands), rtol=1e-12)
    wide = CoverageEnv(_scenario(ROBOTS, SimParams(num_robots=len(ROBOTS), num_features=3, comm_radius_m=2000.0)))
    np.testing.assert_array_equal(select_actions("oracle_hood", wide, cands), select_actions("oracle", wide, cands))
    kept = select_actions("oracle_hood", env, cands)
    pair = (cell[0] + cell[1]).argmin()
    for i, k in ((0, pair), (1, pair), (2, cell[2].argmin()), (3, cell[3].argmin()), (4, cell[4].argmin())):
        np.testing.assert_array_equal(kept[i], cands[k, i])
    assert RULES["oracle_hood"].bound and RULES["oracle_hood"].joint
