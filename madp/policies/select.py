"""Choosing among MADP's samples: every robot draws K candidate actions in one batched
sampling call (K copies of the swarm's state, copy k with its own noise), and one action is kept.

Candidate k of robot i is robot i's action in copy k; copy k as a whole is a joint sample (a swarm
action). The rules (:data:`SELECTS`, ``SamplingSettings(select=..., candidates=K)``):

* ``none``: K = 1, MADP's sampling as it always was.
* ``oracle`` — **an upper bound, not a controller robots could run**: it keeps the joint sample whose
  true coverage cost J after the step (the world map, all robots; :func:`oracle_costs`) is lowest.
  It needs the environment itself.
* ``cell``: each robot, alone, keeps the candidate whose *local cell cost* (:func:`local_cell_costs`)
  is lowest: the cost of its own Voronoi cell after the candidate move, among itself and its
  neighbours within r_c at their latest positions (assumed to stay), on its own sensed map inside its
  local window.
* ``mppi``: each robot takes the mean of its candidates weighted by ``exp(-c_k / λ)`` with c_k the
  same local cell cost (:func:`mppi_weights`), λ = :data:`MPPI_TEMPERATURE` × the standard deviation
  of its K costs.
* ``oracle_cell`` — **an upper bound for** ``cell``, **not a controller robots could run**: the
  ``cell`` rule with the true world map in each robot's window in place of its own sensed map. Its
  gap to ``cell`` is what a perfect prediction of unsensed importance would give that rule; its gap
  to ``oracle`` what choosing robot by robot, one step ahead, loses against choosing joint samples.
* ``explore``: ``cell`` on the robot's own map with a prior on what it has not looked at: every
  block of its window it has not explored (:attr:`madp.sim.robot_maps.RobotMaps.explored`, what its
  own sensor has covered) counts as holding the mean importance per cell of the blocks of its window
  it has explored (any equal mass when those hold none: the ranking is then pure exploration).
  The cell's cost then also falls by moving toward the unexplored part of the cell.
* ``value``: ``explore`` with a learned prior in place of the mean: each unexplored block of the
  robot's window counts at the importance its policy file's map prior
  (:class:`madp.models.map_prior.MapPrior`, ``madp value train``) predicts from the window, and the
  candidate of lowest local cell cost on that map is kept. Needs a policy file that carries one.
* ``value_explore``: ``value`` with ``explore``'s mean as a floor: each unexplored block counts at
  the more of the two, so the robot still goes to look where the network expects little, and goes
  first where it expects much.
* ``value_joint``: ``value``, with one copy per neighbourhood: copy k of every robot's
  neighbourhood starts from the same noise of each robot, so each robot sums its neighbours' ``value``
  costs of copy k with its own (the neighbours whose positions it holds send their K costs in one
  more round of messages, modelled as delivered wherever the position was) and
  keeps its action of the copy of least sum. Robots whose neighbourhoods agree keep actions of one
  joint sample, not each its own best of K different ones.
* ``value_explore_joint``: ``value_joint`` on ``value_explore``'s map (``explore``'s mean as a floor).
* ``oracle_joint`` — **an upper bound for** ``value_joint``, **not a controller robots could run**:
  ``value_joint`` with the true world map in each robot's window (a perfect map prior): what a
  one-step choice of one copy per neighbourhood can reach.
* ``medoid``: each robot keeps the candidate closest to its others (least summed distance,
  :func:`medoid_index`): the most typical of its samples, a mode estimate, from its own candidates only.

A robot that holds no neighbour (out of range, or every message lost) does not choose among its
samples under the rules that read its map (``cell``, ``explore``, the ``value`` rules,
``mppi``, ``oracle_cell``, ``oracle_joint``): it takes the Lloyd step of the disc it would expect to cover around where it last
heard a neighbour (:func:`madp.robot.choice.lone_steps`).

The local rules read only what a robot knows: :func:`local_views` collects, per robot, its own map's
window, its own position and its neighbours' positions; :func:`local_cell_costs` and
:func:`mppi_weights` take nothing else, and row i of their result depends on row i of their inputs
alone. Only :func:`oracle_costs` and the true-map views of ``oracle_cell`` and ``oracle_joint`` read the
world map.

What a robot computes for itself (:func:`local_views`, :func:`explore_prior`, :func:`local_cell_costs`,
:func:`mppi_weights`, :func:`medoid_index`) lives in :mod:`madp.robot.choice` (no torch, so the robot runtime uses it too) and
is re-exported here.
"""

from __future__ import annotations

import numpy as np

from madp.errors import SettingError
from madp.robot.choice import (GRID_M, MPPI_TEMPERATURE, LocalViews, explore_prior, local_cell_costs, local_views,
                               joint_copy, lone_steps, medoid_index, mppi_weights)
from madp.robot.prior import value_view
from madp.sim.env import CoverageEnv, move
from madp.sim.voronoi import coverage_cost

#: The selection rules (module docstring).
SELECTS = ("none", "oracle", "cell", "mppi", "medoid", "explore", "oracle_cell", "value", "value_explore", "value_joint",
           "value_explore_joint", "oracle_joint")
#: The rules that read the world map: upper bounds, not controllers robots could run.
ORACLE_RULES = ("oracle", "oracle_cell", "oracle_joint")
#: The rules that rank candidates on a policy file's learned map prior (madp value train).
VALUE_RULES = ("value", "value_explore", "value_joint", "value_explore_joint")
#: The rules that keep one copy per neighbourhood (:func:`madp.robot.choice.joint_copy`).
JOINT_RULES = ("value_joint", "value_explore_joint", "oracle_joint")
#: The rule MADP uses unless told otherwise (README, Choosing among MADP's samples).
DEFAULT_SELECT = "explore"
#: K for a rule named without a number of candidates.
DEFAULT_CANDIDATES = 4
#: The most candidates per robot: K samples cost K denoiser passes and K × N actions per step.
MAX_CANDIDATES = 1024


def default_candidates(select: str) -> int:
    """K when only the rule is given: 1 for ``none``, :data:`DEFAULT_CANDIDATES` for any other rule."""
    return 1 if select == "none" else DEFAULT_CANDIDATES


def check_selection(select: str, candidates: int) -> None:
    """A one-line :class:`SettingError` unless ``select`` is one of :data:`SELECTS` and ``candidates``
    K fits it: ``none`` with K = 1, any other rule with 1 < K <= :data:`MAX_CANDIDATES`."""
    if select not in SELECTS:
        raise SettingError("select", f"expected one of {', '.join(SELECTS)}, got {select!r}")
    if isinstance(candidates, bool) or not isinstance(candidates, (int, np.integer)) or candidates < 1:
        raise SettingError("candidates", f"expected a whole number of samples per robot >= 1, got {candidates!r}")
    if candidates > MAX_CANDIDATES:
        raise SettingError("candidates", f"expected at most {MAX_CANDIDATES} samples per robot, got {candidates}")
    if select == "none" and candidates > 1:
        raise SettingError("select/candidates", f"{candidates} candidates per robot need a rule to choose among "
                           "them (" + ", ".join(SELECTS[1:]) + "), got select none")
    if select != "none" and candidates == 1:
        raise SettingError("select/candidates", f"select {select} chooses among several samples per robot: "
                           "expected candidates > 1, got 1")


def oracle_costs(env: CoverageEnv, actions_mps: np.ndarray) -> np.ndarray:
    """The true J after one step of each joint sample ``actions_mps [K, N, 2]`` (m/s): ``[K]``. The
    positions move as :meth:`CoverageEnv.step` moves them (:func:`madp.sim.env.move`); ``env`` is
    left as it is. Reads the whole world map: an oracle, not something robots could compute."""
    pos, _ = move(env.start_m, env.offset_m, actions_mps, env.params)
    return np.array([coverage_cost(env.prefix, p) for p in pos])


def value_views(env: CoverageEnv, views: LocalViews, map_prior, floor: bool = False) -> LocalViews:
    """``views`` with the ``value`` rule's weights: each robot's unexplored blocks inside the world
    given ``map_prior``'s prediction (:func:`madp.robot.prior.value_view`); ``floor``: at least
    ``explore``'s mean (``value_explore``)."""
    from madp.models.map_prior import predictor

    return value_view(env.maps, views, predictor(map_prior), floor)


def select_actions(select: str, env: CoverageEnv, candidates_mps: np.ndarray, map_prior=None) -> np.ndarray:
    """The swarm's action ``[N, 2]`` kept by rule ``select`` among ``candidates_mps [K, N, 2]``
    (copy k of the batch in row k; module docstring). ``oracle`` reads the environment; ``cell`` and
    ``mppi`` only each robot's :func:`local_views`; ``medoid`` only each robot's own candidates;
    ``explore`` those and its own explored map; ``value`` those and ``map_prior``
    (:class:`madp.models.map_prior.MapPrior`); ``oracle_cell`` and ``oracle_joint`` the true-map views."""
    if select == "none":
        return candidates_mps[0]
    if select == "oracle":
        return candidates_mps[int(np.argmin(oracle_costs(env, candidates_mps)))]
    per_robot = candidates_mps.transpose(1, 0, 2)  # [N, K, 2]
    if select == "medoid":
        return np.take_along_axis(per_robot, medoid_index(per_robot)[:, None, None], 1)[:, 0]
    views = local_views(env, true_map=select in ORACLE_RULES)
    if select == "explore":
        views = explore_prior(env, views)
    if select in VALUE_RULES:
        if map_prior is None:
            raise SettingError("select", f"{select} scores candidates on a learned map prior: expected a policy file "
                                         "that carries one (madp value train)")
        views = value_views(env, views, map_prior, floor=select in ("value_explore", "value_explore_joint"))
    costs = local_cell_costs(views, per_robot, env.params)
    if select in JOINT_RULES:
        chosen = np.take_along_axis(per_robot, joint_copy(costs, env.neighbour_view()[0])[:, None, None], 1)[:, 0]
    elif select in ("cell", "explore", "oracle_cell", "value", "value_explore"):
        chosen = np.take_along_axis(per_robot, costs.argmin(1)[:, None, None], 1)[:, 0]
    elif select == "mppi":
        chosen = np.einsum("nk,nkd->nd", mppi_weights(costs, MPPI_TEMPERATURE), per_robot)
    else:
        raise SettingError("select", f"expected one of {', '.join(SELECTS)}, got {select!r}")
    lone, steps = lone_steps(views, env.params)  # a robot that hears no one: its bounded Lloyd step
    return np.where(lone[:, None], steps, chosen)
