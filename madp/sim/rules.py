"""The rules the simulator, the policies and the robot runtime share, one home each: who is closer than
r_c, and the controllers' speed clip. numpy only (the robot runtime imports it); the model's twin of
the squared rule, on torch tensors, is :func:`madp.models.attention_mask.closer_than_squared`.

"Closer than r_c" is written in two ways, and they are two rules, not one: at the boundary they can
disagree (``sqrt`` rounds a sum just below r² up to r), so each place keeps the one it has always used:

* :func:`closer_than` (float64, ``‖d‖ < r``): the simulator's. The network's range
  (:meth:`madp.sim.network.Network.in_range`), the neighbours of the true state
  (:meth:`madp.sim.CoverageEnv.neighbours`), those a robot knows of (:func:`madp.sim.env.within_reach`),
  the observations' neighbour channels and the environments' neighbour tables;
* :func:`closer_than_squared` (``d·d < r·r`` in the offsets' own precision, r·r rounded to it): the
  learned side's. float32 in the robot runtime (:class:`madp.robot.RobotRuntime`) and, on tensors, in
  the model's attention window and LPAC-K3's graph (the twin named above: the same comparison, since
  torch compares a float32 tensor with r·r rounded to float32); float64 in the inbox's default range
  check (:func:`madp.robot.read_inbox`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["clip_speed", "closer_than", "closer_than_squared", "distances_m"]


def distances_m(offsets_m: np.ndarray) -> np.ndarray:
    """``[...]``: the Euclidean length of each offset ``offsets_m [..., 2]`` (``np.linalg.norm``, in the
    offsets' precision: float64, as the simulator's positions are)."""
    return np.linalg.norm(offsets_m, axis=-1)


def closer_than(offsets_m: np.ndarray, radius_m: float) -> np.ndarray:
    """``[...]`` bool: the simulator's rule, ``‖d‖ < r`` in float64, for each offset ``d`` of
    ``offsets_m [..., 2]`` and r = ``radius_m``."""
    return distances_m(offsets_m) < radius_m


def closer_than_squared(offsets: np.ndarray, radius_m: float) -> np.ndarray:
    """``[...]`` bool: the learned side's rule, ``d·d < r·r`` computed in the precision of ``offsets
    [..., 2]`` (float32 or float64), r·r rounded to it."""
    offsets = np.asarray(offsets)
    return (offsets ** 2).sum(-1) < offsets.dtype.type(radius_m * radius_m)


def clip_speed(u_mps: np.ndarray, u_max_mps: float) -> np.ndarray:
    """``u_mps [..., 2]`` with every speed above ``u_max_mps`` scaled down to it (the direction kept):
    what a controller commands. The simulator's own motion rule (:func:`madp.sim.env.move`) clips
    again, its own way (a unit direction times the clipped speed)."""
    speed = np.linalg.norm(u_mps, axis=-1, keepdims=True)
    return np.where(speed > u_max_mps, u_mps * (u_max_mps / np.maximum(speed, 1e-12)), u_mps)
