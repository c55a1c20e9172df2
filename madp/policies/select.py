"""Choosing among MADP's samples in the simulator: every robot draws K candidate actions in one batched
sampling call (K copies of the swarm's state, copy k with its own noise), and one action is kept.

Candidate k of robot i is robot i's action in copy k; copy k as a whole is a joint sample (a swarm
action). The rules, their help and what each reads are records (:data:`madp.selection.RULES`,
torch-free: the robot runtime chooses with the same code); the documentation's table of them is
``docs/concepts/sampling.md``. Here the simulator's side: every robot's view at once
(:func:`local_views` of the environment; the true map in each window for the bounds that read it), the
true J of each joint sample for ``oracle`` (:func:`oracle_costs`, which reads the world), each robot's
true cell cost of each for ``oracle_hood`` (:func:`oracle_cell_costs`), and the
neighbourhoods of the ``joint`` rules from the environment's links.
"""

from __future__ import annotations

import numpy as np

from madp.errors import SettingError
from madp.robot.choice import GRID_M, LocalViews, explore_prior, joint_copy, local_cell_costs, local_views
from madp.selection import NEEDS, choose, rule, weigh
from madp.sim.env import CoverageEnv, move
from madp.sim.voronoi import coverage_cost, world_sums

__all__ = ["GRID_M", "LocalViews", "explore_prior", "local_cell_costs", "local_views", "oracle_cell_costs", "oracle_costs",
           "predictor_of", "select_actions"]


def oracle_costs(env: CoverageEnv, actions_mps: np.ndarray) -> np.ndarray:
    """The true J after one step of each joint sample ``actions_mps [K, N, 2]`` (m/s): ``[K]``. The
    positions move as :meth:`CoverageEnv.step` moves them (:func:`madp.sim.env.move`); ``env`` is
    left as it is. Reads the whole world map: an oracle, not something robots could compute."""
    pos, _ = move(env.start_m, env.offset_m, actions_mps, env.params)
    return np.array([coverage_cost(env.prefix, p) for p in pos])


def oracle_cell_costs(env: CoverageEnv, actions_mps: np.ndarray) -> np.ndarray:
    """Each robot's true cost of its whole Voronoi cell on the world map after one step of each joint
    sample ``actions_mps [K, N, 2]``: ``[N, K]``; column k sums to :func:`oracle_costs`' entry k."""
    pos, _ = move(env.start_m, env.offset_m, actions_mps, env.params)
    return np.stack([world_sums(env.prefix, p, True, with_centroids=False).cost for p in pos], 1)


def predictor_of(network):
    """The numpy-in, numpy-out ``predict`` of a policy file's learned network: its map prior
    (:class:`madp.models.map_prior.MapPrior`) or its critic (:class:`madp.models.critic.Critic`); None for None."""
    if network is None:
        return None
    from madp.models.critic import Critic, critic_predictor
    from madp.models.map_prior import predictor

    return critic_predictor(network) if isinstance(network, Critic) else predictor(network)


def select_actions(select: str, env: CoverageEnv, candidates_mps: np.ndarray, network=None) -> np.ndarray:
    """The swarm's action ``[N, 2]`` kept by rule ``select`` among ``candidates_mps [K, N, 2]``
    (copy k of the batch in row k): ``oracle`` by the true J of each joint sample; every other rule by
    :func:`madp.selection.choose` on each robot's :func:`local_views` (the true map's for the
    bounds that read it) weighed by the rule, ``network`` the policy file's learned network the rule
    needs (:attr:`madp.selection.Rule.needs`: a map prior or a critic, :func:`madp.policies.checkpoint.load_learned`)."""
    r = rule(select)
    per_robot = candidates_mps.transpose(1, 0, 2)  # [N, K, 2]
    if r.sees == "world" and r.joint:  # each neighbourhood's copy of least true J over its robots' cells
        index = joint_copy(oracle_cell_costs(env, candidates_mps), env.neighbour_view()[0])
        return np.take_along_axis(per_robot, index[:, None, None], 1)[:, 0]
    if r.sees == "world":
        return candidates_mps[int(np.argmin(oracle_costs(env, candidates_mps)))]
    if not r.ranks:
        return choose(r, per_robot, None, env.params)[0]
    if r.needs and network is None:
        raise SettingError("select", f"{select} reads a learned {r.needs}: expected a policy file that carries one "
                                     f"({NEEDS[r.needs].made_by})")
    predict = predictor_of(network)
    views = weigh(r, env.maps, local_views(env, true_map=r.sees == "true map"), predict)
    return choose(r, per_robot, views, env.params, env.neighbour_view()[0] if r.joint else None, predict)[0]
