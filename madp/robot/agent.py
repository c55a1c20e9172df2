"""One robot as it runs on its own: what it knows, built from what reaches it alone.

A :class:`RobotAgent` holds one robot's state: its sensed map and explored map (one robot's padded
map, :class:`madp.sim.robot_maps.RobotMaps` of one robot with no world map), written from its own
sensor's readings only (:class:`SensorReading`), and its own position estimate (with its start, for
the motion rule). Per control step t it is driven in three calls, as its radio brings messages:

1. :meth:`RobotAgent.observe`: its position estimate and its sensor's reading of step t;
   :meth:`RobotAgent.beacon` is then its position beacon ``Message(id, t, position)``;
2. :meth:`RobotAgent.token`: from the beacons its radio delivered, its observation ``[4, 32, 32]``
   (its own map's window, the neighbours within r_c of its own estimate, the border), its selection
   view from its own maps (:func:`madp.robot.choice.map_views`, with its rule's prior:
   :meth:`madp.robot.RobotRuntime.view`) and its token message (:meth:`madp.robot.RobotRuntime.message`);
3. :meth:`RobotAgent.act`: from the token messages its radio delivered, its selection view and the
   exported policy (:meth:`madp.robot.RobotRuntime.step`; starting noise :func:`robot_noise` of the
   swarm's seed, the step and the neighbourhood's ids) -> :class:`madp.robot.StepResult`;
4. under a ``_joint`` rule (``runtime.joint``) the action of step 3 is provisional:
   :meth:`RobotAgent.costs` is its cost message, and :meth:`RobotAgent.choose`, from the cost
   messages its radio delivered, the action it applies.

The observation, the view and the token are computed by the same functions the simulator computes
for every robot at once (:meth:`madp.sim.CoverageEnv.observations`, :func:`madp.robot.choice.local_views`),
so an agent fed robot i's readings, estimate and delivered messages holds row i of theirs, bit for
bit (tests/robot/test_agent.py). numpy, numba and onnxruntime only: nothing here imports torch.
"""

from __future__ import annotations

import numpy as np

from madp.sim.env import within_reach
from madp.sim.network import Message
from madp.sim.params import SimParams
from madp.sim.robot_maps import RobotMaps, SensorReading

from .choice import LocalViews, map_views
from .inbox import read_inbox
from .runtime import RobotRuntime, StepResult

__all__ = ["RobotAgent", "SensorReading"]

class RobotAgent:
    """Robot ``robot_id`` of a swarm running the exported policy ``runtime`` in the world of
    ``params`` (its sizes: world, sensor, window, observation, r_c), in the episode of ``seed`` (the
    swarm's shared seed: its frames and starting noise). ``exact_position``: its position estimates
    are its true positions (no localisation noise): the motion rule then integrates from its start
    (its first estimate) as the world does, else from each step's estimate. Beacons and tokens older
    than ``runtime.max_age`` steps are not used (None: any age).

    Attributes after :meth:`token`: ``observation [4, S, S]`` float32 and ``view``, its
    :class:`LocalViews` row (None when its rule reads no map)."""

    def __init__(self, robot_id: int, runtime: RobotRuntime, params: SimParams, seed: int,
                 exact_position: bool = True):
        self.robot_id, self.runtime, self.params, self.seed = int(robot_id), runtime, params, int(seed)
        self.exact_position = bool(exact_position)
        self.maps = RobotMaps(None, 1, params.sensor_size, params.local_map_size, world_size=params.world_size)
        self.step: int | None = None
        self.position_m: np.ndarray | None = None
        self.start_m: np.ndarray | None = None
        self.anchor_m: np.ndarray | None = None  # where it last heard a neighbour (its first position until then)
        self.observation: np.ndarray | None = None
        self.view: LocalViews | None = None
        self._message: Message | None = None
        self._known: np.ndarray = np.zeros(0, np.int64)  # ids of the neighbours it holds this step
        self._result: StepResult | None = None

    def observe(self, step: int, position_m: np.ndarray, reading: SensorReading) -> None:
        """Start of control step ``step``: its own position estimate ``position_m [2]`` (m) and its
        sensor's reading; what the reading holds outside the world is not kept."""
        s = 2 * self.maps.sensor_half
        lo = np.asarray(reading.lo_cell, dtype=np.int64).reshape(2)
        values = np.asarray(reading.values, dtype=np.float32)
        if values.shape != (s, s):
            raise ValueError(f"robot {self.robot_id}: expected a {s} × {s} sensor reading, got {values.shape}")
        w = self.params.world_size
        span = lo[:, None] + np.arange(s)  # [2, s]: the world cells of the reading per axis
        inside = (span >= 0) & (span < w)
        self.maps.record(lo[None], np.where(inside[0][:, None] & inside[1][None, :], values, np.float32(0))[None])
        self.step = int(step)
        self.position_m = np.array(position_m, dtype=np.float64).reshape(2)
        if self.start_m is None:
            self.start_m = self.position_m.copy()
        self.observation, self.view, self._message, self._result = None, None, None, None

    def beacon(self) -> Message:
        """Its position beacon of this step: ``Message(robot_id, step, position_m)`` (no token)."""
        self._started("beacon")
        return Message(self.robot_id, self.step, self.position_m.copy())

    def token(self, beacons: list) -> Message:
        """From the position beacons its radio delivered (any objects: those that are not a usable
        :class:`Message`, its own, from a later step or older than ``runtime.max_age`` are dropped,
        and of a sender's several the newest is kept; never raised), its neighbours (those within r_c of
        its own estimate), its observation, its selection view and its token message of this step."""
        self._started("token")
        own = self.position_m[None]
        ids, held = self._beacon_positions(beacons)  # [M], [M, 2], ascending by sender
        known = within_reach(own, held[None], self.params.comm_radius_m)[0]
        self._known = ids[known]
        p = self.params
        self.observation = self.maps.observations(own, p.comm_radius_m, p.obs_size, view=(known[None], held[None]))[0]
        self.view = self._view(known, held) if self.runtime.reads_map else None
        self._message = self.runtime.message(self.robot_id, self.step, self.observation, self.position_m,
                                             held[known], self.seed)
        return self._message

    def act(self, tokens: list) -> StepResult:
        """From the token messages its radio delivered (checked by :func:`madp.robot.read_inbox`),
        its control step: :meth:`madp.robot.RobotRuntime.step` with its selection view -> the action
        ``[2]`` (m/s, world axes), its K candidates, its message and its inbox's counts."""
        if self._message is None:
            raise RuntimeError(f"robot {self.robot_id}: act() before token() at this step")
        self._result = self.runtime.step(self.robot_id, self.step, self.observation, self.position_m, tokens,
                                         self.seed, view=self.view, own=self._message)
        return self._result

    def costs(self) -> Message:
        """Under a ``_joint`` rule, after :meth:`act`: its cost message of this step (its K costs)."""
        if self._result is None:
            raise RuntimeError(f"robot {self.robot_id}: costs() before act() at this step")
        return self.runtime.cost_message(self._result)

    def choose(self, costs: list) -> np.ndarray:
        """Under a ``_joint`` rule, after :meth:`act`: from the cost messages its radio delivered (those
        of the neighbours it holds count, :meth:`madp.robot.RobotRuntime.choose_joint`), the action ``[2]``
        (m/s, world axes) it applies."""
        if self._result is None:
            raise RuntimeError(f"robot {self.robot_id}: choose() before act() at this step")
        return self.runtime.choose_joint(self._result, costs, self._known)

    # ------------------------------------------------------------------------------------ helpers
    def _started(self, what: str) -> None:
        if self.step is None:
            raise RuntimeError(f"robot {self.robot_id}: {what}() before its first observe()")

    def _view(self, known: np.ndarray, held: np.ndarray) -> LocalViews:
        """Its :class:`LocalViews` row (R = 1) from its own maps, estimate and the neighbours it knows
        of (``held [M, 2]`` where ``known [M]``)."""
        own = self.position_m[None]
        if self.exact_position:
            start, offset = self.start_m[None], own - self.start_m[None]
        else:
            start, offset = own, np.zeros_like(own)
        if self.anchor_m is None or known.any():
            self.anchor_m = self.position_m.copy()
        view = map_views(self.maps, own, start, offset, known[None], held[None], anchor_m=self.anchor_m[None])
        return self.runtime.view(self.maps, view)

    def _beacon_positions(self, beacons) -> tuple[np.ndarray, np.ndarray]:
        """The senders ``[M]`` and positions ``[M, 2]`` float64 of the usable beacons
        (:func:`madp.robot.read_inbox`'s rules for a message without a token; the range is applied by
        the caller), ascending by sender."""
        kept, _ = read_inbox(beacons, self.robot_id, self.step, self.position_m, None, self.params.comm_radius_m,
                             within=lambda pos: np.ones(len(pos), bool), max_age=self.runtime.max_age)
        return (np.array([i for i, _, _ in kept], dtype=np.int64),
                np.array([p for _, p, _ in kept], dtype=np.float64).reshape(-1, 2))
