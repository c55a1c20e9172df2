"""Choosing among MADP's samples in the simulator: every robot draws K candidate actions in one batched
sampling call (K copies of the swarm's state, copy k with its own noise), and one action is kept.

Candidate k of robot i is robot i's action in copy k; copy k as a whole is a joint sample (a swarm
action). The rules, their help and what each reads are records (:data:`madp.selection.RULES`,
torch-free: the robot runtime chooses with the same code); the documentation's table of them is
``docs/concepts/sampling.md``. Here the simulator's side: every robot's view at once
(:func:`local_views` of the environment; the true map in each window for the bounds that read it), the
true J of each joint sample for ``oracle`` (:func:`oracle_costs`, which reads the world), and the
neighbourhoods of the ``joint`` rules from the environment's links.
"""

from __future__ import annotations

import numpy as np

from madp.errors import SettingError
from madp.robot.choice import GRID_M, LocalViews, explore_prior, local_cell_costs, local_views
from madp.selection import choose, rule, weigh
from madp.sim.env import CoverageEnv, move
from madp.sim.voronoi import coverage_cost

__all__ = ["GRID_M", "LocalViews", "explore_prior", "local_cell_costs", "local_views", "oracle_costs", "predictor_of",
           "select_actions"]


def oracle_costs(env: CoverageEnv, actions_mps: np.ndarray) -> np.ndarray:
    """The true J after one step of each joint sample ``actions_mps [K, N, 2]`` (m/s): ``[K]``. The
    positions move as :meth:`CoverageEnv.step` moves them (:func:`madp.sim.env.move`); ``env`` is
    left as it is. Reads the whole world map: an oracle, not something robots could compute."""
    pos, _ = move(env.start_m, env.offset_m, actions_mps, env.params)
    return np.array([coverage_cost(env.prefix, p) for p in pos])


def predictor_of(map_prior):
    """The torch-free ``predict`` of a policy file's map prior (:class:`madp.models.map_prior.MapPrior`), or None."""
    if map_prior is None:
        return None
    from madp.models.map_prior import predictor

    return predictor(map_prior)


def select_actions(select: str, env: CoverageEnv, candidates_mps: np.ndarray, map_prior=None) -> np.ndarray:
    """The swarm's action ``[N, 2]`` kept by rule ``select`` among ``candidates_mps [K, N, 2]``
    (copy k of the batch in row k): ``oracle`` by the true J of each joint sample; every other rule by
    :func:`madp.selection.choose` on each robot's :func:`local_views` (the true map's for the
    bounds that read it) weighed by the rule, ``map_prior`` (:class:`madp.models.map_prior.MapPrior`)
    for the rules that need one."""
    r = rule(select)
    if r.sees == "world":
        return candidates_mps[int(np.argmin(oracle_costs(env, candidates_mps)))]
    per_robot = candidates_mps.transpose(1, 0, 2)  # [N, K, 2]
    if not r.ranks:
        return choose(r, per_robot, None, env.params)[0]
    if r.prior and map_prior is None:
        raise SettingError("select", f"{select} scores candidates on a learned map prior: expected a policy file "
                                     "that carries one (madp value train)")
    views = weigh(r, env.maps, local_views(env, true_map=r.sees == "true map"), predictor_of(map_prior))
    return choose(r, per_robot, views, env.params, env.neighbour_view()[0] if r.joint else None)[0]
