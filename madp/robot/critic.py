"""A learned critic of MADP's joint copies, on the robot's side (numpy, no torch): what the network reads
of a robot's window, the score of each copy it turns the network's output into, and the choice of a
copy per robot, per neighbourhood or for the whole team.

**What the critic predicts.** One control step moves a robot at most u_max·Δt (1 m), far less than its
Voronoi cell's size, so the true change of the coverage cost J that a joint copy k causes is, to
second order in the moves and up to the cells' boundaries moving (which changes J at second order
only), ``Σ_i M_i (|δ_ik − d_i|² − |d_i|²)``: M_i the true mass of robot i's cell, d_i = C_i − x_i the
offset of its true centroid from its position, δ_ik robot i's move in copy k. Both are properties of
the whole cell, which reaches far into land the robot has not sensed. The network
(:class:`madp.models.critic.Critic`) predicts them, per robot, from what the robot knows (its window,
:func:`critic_inputs` of its :func:`critic_view`), and :func:`copy_scores` turns them into each copy's predicted change of J
for that robot's part, ``s_ik``. A copy's team score is ``Σ_i s_ik``; a neighbourhood's, the sum over
the robots whose positions the robot holds (one more round of messages, as ``value_joint``'s costs).

The inputs, per robot, over its window coarsened to :data:`madp.robot.prior.COARSE_M` m cells
(``[R, 5, 16, 16]`` float32 for the 256 m window): the map prior's three channels
(:func:`madp.robot.prior.window_inputs`), the fraction of each cell closer to the robot than to every
neighbour it holds (its local Voronoi cell, :func:`own_cell_fraction`), and how many of those
neighbours are in the cell; and the offsets of its nearest neighbours, those beyond its window too
(:func:`neighbour_features`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from madp.errors import SettingError
from madp.sim.env import move
from madp.sim.params import SimParams

from .choice import GRID_M, LocalViews, map_prior, unexplored_blocks
from .prior import COARSE_M, coarse_sum, prior_inputs, window_masks

if TYPE_CHECKING:
    from madp.sim.robot_maps import RobotMaps

__all__ = ["CRITIC_CHANNELS", "CRITIC_SCOPES", "MAX_NEIGHBOURS", "OFFSET_SCALE_M", "copy_scores", "critic_choice",
           "critic_costs", "critic_inputs", "critic_view", "displacements_m", "neighbour_counts", "neighbour_features", "onnx_predictor",
           "own_cell_fraction"]

#: Input channels: the map prior's three, the own-cell fraction, the neighbours per coarse cell.
CRITIC_CHANNELS = 5
#: Where the copies' scores are summed before the choice: each robot alone, each robot's
#: neighbourhood (itself and the robots whose positions it holds), or the whole team (one copy).
CRITIC_SCOPES = ("robot", "neighbourhood", "team")
#: The network predicts the centroid offset d_i in units of this many metres (half the window).
OFFSET_SCALE_M = 128.0
#: The nearest neighbours whose offsets the network reads (:func:`neighbour_features`).
MAX_NEIGHBOURS = 16


def own_cell_fraction(views: LocalViews) -> np.ndarray:
    """``[R, H, H]`` float32: per coarse cell of each robot's window, the fraction of its GRID_M blocks
    whose centre is no farther from the robot (``start_m + offset_m``) than from every valid neighbour."""
    g = views.weights.shape[1]
    centre = np.arange(g) * GRID_M + GRID_M / 2
    qx = views.origin_m[:, 0, None] + centre[None]  # [R, G]
    qy = views.origin_m[:, 1, None] + centre[None]
    own = views.start_m + views.offset_m

    def d2(p):  # [R, G, G]: squared distance of every block centre to points p [R, 2]
        return (qx - p[:, 0, None])[:, :, None] ** 2 + (qy - p[:, 1, None])[:, None, :] ** 2

    mine = d2(own)
    nearest = np.full_like(mine, np.inf)
    for m in range(views.neighbours_m.shape[1]):
        other = d2(views.neighbours_m[:, m])
        nearest = np.where(views.valid[:, m, None, None], np.minimum(nearest, other), nearest)
    f = COARSE_M // GRID_M
    return (coarse_sum((mine <= nearest).astype(np.float32), f) / f ** 2).astype(np.float32)


def neighbour_counts(views: LocalViews) -> np.ndarray:
    """``[R, H, H]`` float32: how many of each robot's valid neighbours lie in each coarse cell of its window."""
    r, g = views.weights.shape[0], views.weights.shape[1] * GRID_M // COARSE_M
    cell = np.floor((views.neighbours_m - views.origin_m[:, None]) / COARSE_M).astype(np.int64)  # [R, M, 2]
    ok = views.valid & (cell >= 0).all(-1) & (cell < g).all(-1)
    out = np.zeros((r, g, g), np.float32)
    rows = np.broadcast_to(np.arange(r)[:, None], ok.shape)
    np.add.at(out, (rows[ok], cell[..., 0][ok], cell[..., 1][ok]), 1.0)
    return out


def neighbour_features(offsets_m: np.ndarray, valid: np.ndarray, comm_radius_m: float) -> np.ndarray:
    """``[R, MAX_NEIGHBOURS, 3]`` float32: the offsets of each robot's nearest valid neighbours
    ``offsets_m [R, M, 2]`` (neighbour minus robot, m) in units of r_c, and 1 for a real one (0 rows
    pad), nearest first: what the network reads of the neighbours beyond its window too."""
    offsets_m = np.asarray(offsets_m, np.float64)
    r = len(offsets_m)
    d2 = np.where(valid, (offsets_m ** 2).sum(-1), np.inf)
    order = np.argsort(d2, axis=1, kind="stable")[:, :MAX_NEIGHBOURS]
    out = np.zeros((r, MAX_NEIGHBOURS, 3), np.float32)
    m = order.shape[1]
    out[:, :m, :2] = np.take_along_axis(offsets_m, order[:, :, None], 1) / comm_radius_m
    out[:, :m, 2] = np.take_along_axis(np.asarray(valid, bool), order, 1)
    out[:, :, :2] *= out[:, :, 2:]
    return out


def critic_view(maps: RobotMaps, views: LocalViews) -> LocalViews:
    """``views`` (rows of the robots of ``maps``) as the ``critic`` rules hold them: ``explore``'s map
    (:func:`madp.robot.choice.map_prior`: a lone robot's step reads it; ``sensed`` keeps the sensed
    map) and each window's unexplored blocks, all :func:`critic_inputs` reads of the robots' maps."""
    return replace(map_prior(maps, views), unexplored=unexplored_blocks(maps, views))


def critic_inputs(views: LocalViews, params: SimParams) -> tuple[np.ndarray, np.ndarray]:
    """The critic's inputs (module docstring) from the robots' :func:`critic_view` rows: their windows
    ``[R, 5, H, H]`` float32 (the sensed map: ``views.sensed``, else ``views.weights``) and their
    nearest neighbours' offsets ``[R, MAX_NEIGHBOURS, 3]`` (:func:`neighbour_features`); ``params``:
    the world's size and r_c."""
    if views.unexplored is None:
        raise ValueError("critic_inputs reads each window's unexplored blocks: pass critic_view's rows")
    sensed = views.weights if views.sensed is None else views.sensed
    inside = window_masks(views.origin_m, sensed.shape[1], GRID_M, params.world_size)
    x = prior_inputs(sensed, views.unexplored, inside, GRID_M)
    windows = np.concatenate([x, own_cell_fraction(views)[:, None], neighbour_counts(views)[:, None]], 1)
    own = views.start_m + views.offset_m
    return windows, neighbour_features(views.neighbours_m - own[:, None], views.valid, params.comm_radius_m)


def displacements_m(views: LocalViews, candidates_mps: np.ndarray, params: SimParams) -> np.ndarray:
    """``[R, K, 2]``: each robot's move over one step (m) under its candidates ``candidates_mps [R, K, 2]``,
    by the motion rule (:func:`madp.sim.env.move`) from its position as it integrates it."""
    y, _ = move(views.start_m[:, None], views.offset_m[:, None], candidates_mps, params)
    return y - (views.start_m + views.offset_m)[:, None]


def copy_scores(mass: np.ndarray, offset_m: np.ndarray, displacement_m: np.ndarray) -> np.ndarray:
    """``[R, K]``: each robot's share of the change of J of each copy, ``M (|δ − d|² − |d|²)``, from
    the cell's mass ``mass [R]`` (≥ 0), its centroid's offset from the robot ``offset_m [R, 2]`` and the
    robot's moves ``displacement_m [R, K, 2]`` (lower is better)."""
    d = np.asarray(offset_m, np.float64)[:, None]
    delta = np.asarray(displacement_m, np.float64)
    return np.asarray(mass, np.float64)[:, None] * ((delta ** 2).sum(-1) - 2.0 * (delta * d).sum(-1))


def critic_choice(scores: np.ndarray, neighbours: np.ndarray, scope: str) -> np.ndarray:
    """``[R]``: the copy each robot keeps, from the copies' scores ``scores [R, K]`` (robot i's share
    of copy k) and ``neighbours [R, R]`` bool (robot i holds robot j's scores this step): ``robot`` the
    least of its own, ``neighbourhood`` the least sum over itself and those it holds, ``team`` the
    least sum over all robots (one copy for everyone; ties: the lowest k)."""
    scores = np.asarray(scores, np.float64)
    if scope == "robot":
        return scores.argmin(1)
    if scope == "neighbourhood":
        near = np.asarray(neighbours, bool) | np.eye(len(scores), dtype=bool)
        return (near.astype(np.float64) @ scores).argmin(1)
    if scope == "team":
        return np.full(len(scores), int(scores.sum(0).argmin()))
    raise SettingError("scope", f"expected one of {', '.join(CRITIC_SCOPES)}, got {scope!r}")


def critic_costs(views: LocalViews, candidates_mps: np.ndarray, params: SimParams, predict) -> np.ndarray:
    """``[R, K]``: each robot's predicted share of the change of J of each of its candidates
    ``candidates_mps [R, K, 2]`` (m/s; :func:`copy_scores`, lower is better), the ``critic`` rules'
    ``score`` (:data:`madp.selection.RULES`). ``views``: the robots' :func:`critic_view` rows, read
    through :func:`critic_inputs`; ``predict(windows, neighbours) -> (mass [R], offset_m [R, 2])``:
    :func:`madp.models.critic.critic_predictor` or :func:`onnx_predictor`."""
    cand = np.asarray(candidates_mps, np.float64)
    if cand.ndim != 3 or cand.shape[2] != 2 or cand.shape[0] != len(views.start_m):
        raise SettingError("candidates_mps", f"expected [{len(views.start_m)}, K, 2], got {list(cand.shape)}")
    mass, offset_m = predict(*critic_inputs(views, params))
    return copy_scores(mass, offset_m, displacements_m(views, cand, params))


def onnx_predictor(path, threads: int = 1):
    """The exported critic (``madp critic export``, :func:`madp.export.onnx.export_critic`) as
    :func:`critic_costs`' ``predict``, on onnxruntime's CPU provider with ``threads`` threads:
    ``(windows [R, 5, H, H], neighbours [R, MAX_NEIGHBOURS, 3])`` -> ``(mass [R], offset_m [R, 2])``
    float64. A one-line error for a missing or damaged graph."""
    import onnxruntime as ort

    from madp.errors import InputError

    opts = ort.SessionOptions()
    opts.intra_op_num_threads, opts.inter_op_num_threads = int(threads), 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    try:
        session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime's own error types for a missing or damaged graph
        raise InputError(f"{path}: not a loadable ONNX graph ({type(e).__name__})") from None

    def predict(windows: np.ndarray, near: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mass, offset = session.run(None, {"windows": np.ascontiguousarray(windows, np.float32),
                                          "neighbours": np.ascontiguousarray(near, np.float32)})
        return mass.astype(np.float64), offset.astype(np.float64) * OFFSET_SCALE_M

    return predict
