"""The coverage world a stranger can drive in three lines::

    env = CoverageEnv(Scenario.random(seed=0))
    expert = ClairvoyantCVT()
    for _ in range(600): env.step(expert(env))

``network=NetworkSettings(...)`` puts a network between the robots (:mod:`madp.sim.network`): each
robot then knows its neighbours only through what it has received (:meth:`CoverageEnv.neighbour_view`,
the observations' neighbour channels, the controllers), its own position only through its estimate
(:meth:`CoverageEnv.estimates_m`), failed robots stop, and the cost counts the survivors. Without one
(``network=None``) every robot reads the others' true current state, as the batched computation always has.

State: the fixed world map Φ (and its column prefix sums), robot positions (m), what each robot has
sensed, and the short position history the library uses to detect oscillation. Rules follow the
Coverage Control Library (SPEC §2): holonomic single integrators, speed clipped to u_max, positions
at or beyond the border put back 1e-4 m inside it, sensing after every step.
"""

from __future__ import annotations

import numpy as np

from .idf import importance_map
from .network import Message, Network, NetworkSettings, Received
from .params import SimParams
from .robot_maps import RobotMaps, SensorReading, robot_cells
from .rules import closer_than
from .scenario import Scenario, ScenarioError
from .voronoi import ColumnPrefix, coverage_cost

BORDER_EPS_M = 1e-4
SPEED_EPS = 1e-10


def move(start_m: np.ndarray, offset_m: np.ndarray, actions_mps: np.ndarray, params: SimParams
         ) -> tuple[np.ndarray, np.ndarray]:
    """The motion of one control step, the rule :meth:`CoverageEnv.step` executes, as a pure function:
    robots at ``start_m + offset_m`` driven by ``actions_mps`` (m/s), all ``[..., 2]`` and broadcast
    against each other. The speed is clipped to u_max, a robot slower than 1e-10 m/s stays, the
    start-relative offset is integrated over Δt (the library's order of operations) and positions at
    or beyond the border are put back 1e-4 m inside it. Returns ``(positions, offsets)`` ``[..., 2]``."""
    u = np.asarray(actions_mps, dtype=np.float64)
    speed = np.linalg.norm(u, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        direction = np.where(speed[..., None] > 0, u / speed[..., None], 0.0)
    speed = np.minimum(speed, params.max_speed_mps)
    moving = speed > SPEED_EPS
    new_offset = np.where(moving[..., None], offset_m + direction * (speed * params.dt_s)[..., None], offset_m)
    pos = new_offset + start_m
    w = float(params.world_size)
    pos = np.where(pos <= 0.0, BORDER_EPS_M, pos)
    pos = np.where(pos >= w, w - BORDER_EPS_M, pos)
    return pos, pos - start_m


def within_reach(own_m: np.ndarray, held_m: np.ndarray, comm_radius_m: float) -> np.ndarray:
    """``[R, M]`` bool: which of the positions ``held_m [R, M, 2]`` robot r holds are closer than r_c
    to its own position estimate ``own_m [R, 2]`` (float64, :func:`madp.sim.rules.closer_than`): the
    neighbours it knows of."""
    return closer_than(held_m - own_m[:, None], comm_radius_m)


class CoverageEnv:
    """One episode of decentralized coverage for N robots over a fixed importance map."""

    def __init__(self, scenario: Scenario, world_map: np.ndarray | None = None,
                 network: NetworkSettings | None = None):
        """Build the world from ``scenario``; ``world_map`` [W, W] overrides the map from its features;
        ``network``: what the network between the robots does (None: every robot reads the true state)."""
        self.scenario = scenario
        self.network_settings = network
        self.params: SimParams = scenario.params
        p = self.params
        p.check_fits(f"scenario {scenario.name or scenario.seed}")  # before the maps are allocated
        if world_map is None:
            world_map = importance_map(scenario.features, p.world_size, p.truncation_sigmas)
        self.world_map = np.asarray(world_map, dtype=np.float64)
        self.world_map_f32 = self.world_map.astype(np.float32)
        self.prefix = ColumnPrefix(self.world_map)
        self.reset()

    # --- episode -------------------------------------------------------------------------------
    def reset(self) -> np.ndarray:
        """Put the robots at their start positions, sense, and return positions [N, 2] (m)."""
        p = self.params
        self.start_m = np.array(self.scenario.robots_m, dtype=np.float64)
        self.offset_m = np.zeros_like(self.start_m)  # the library integrates start-relative offsets
        self.positions_m = self.start_m.copy()
        self.num_robots = len(self.start_m)
        self.maps = RobotMaps(self.world_map_f32, self.num_robots, p.sensor_size, p.local_map_size)
        self.maps.sense(robot_cells(self.positions_m))
        self.history: list[np.ndarray] = []
        self._record_history()
        self.steps = 0
        self.network: Network | None = None
        self.anchor_m: np.ndarray | None = None  # where each robot last heard a neighbour (:meth:`_beacon`)
        if self.network_settings is not None:
            seed = self.scenario.seed if self.scenario.seed is not None else 0
            self.network = Network(self.network_settings, self.num_robots, p.comm_radius_m, p.world_size, seed)
        self._beacon()
        self.cost0 = coverage_cost(self.prefix, self.positions_m)
        if not self.cost0 > 0:
            raise ScenarioError(f"scenario {self.scenario.name or self.scenario.seed}: J(0) = {self.cost0} (no importance "
                                "away from the robots), so J(t)/J(0) is undefined")
        return self.positions_m

    def step(self, actions_mps: np.ndarray) -> np.ndarray:
        """Move every robot by Δt · u (speed clipped to u_max), clamp, sense; return positions [N, 2]."""
        u = np.asarray(actions_mps, dtype=np.float64)
        if u.shape != self.positions_m.shape:
            raise ValueError(f"actions must have shape {self.positions_m.shape}, got {u.shape}")
        if not np.isfinite(u).all():
            raise ValueError("actions contain NaN or infinity")
        if self.network is not None:  # failed robots no longer move (nor sense: they stay where they sensed)
            u = np.where(self.network.alive(self.steps)[:, None], u, 0.0)
        pos, self.offset_m = move(self.start_m, self.offset_m, u, self.params)
        self.positions_m = pos
        self.maps.sense(robot_cells(pos))
        self._record_history()
        self.steps += 1
        self._beacon()
        return pos

    def _beacon(self) -> None:
        """The network's step: the true positions, each robot's estimate, and every robot's position
        beacon (the ``position`` channel)."""
        self._received: Received | None = None
        self._estimates = self.positions_m
        if self.network is not None:
            self.network.record(self.steps, self.positions_m)
            self._estimates = self.network.estimates(self.steps, self.positions_m)
            self._received = self.network.exchange("position", self.steps, self._estimates)
        heard = self.neighbour_view()[0].any(1)  # its anchor: its estimate when it hears a neighbour (its first until then)
        self.anchor_m = np.where(heard[:, None], self._estimates, self._estimates if self.anchor_m is None else self.anchor_m)

    def _record_history(self) -> None:
        # The library's deque: when full it drops the oldest entry *instead of* adding the new one.
        if self.history and len(self.history) == self.params.history_size:
            self.history.pop(0)
        else:
            self.history.append(self.positions_m.copy())

    # --- what controllers may look at ----------------------------------------------------------
    def oscillating(self) -> np.ndarray:
        """[N] bool: more than 2 of the last ≤ 6 recorded positions within 1e-4 m of the newest one."""
        if not self.params.check_oscillations or len(self.history) < 3:
            return np.zeros(self.num_robots, dtype=bool)
        k = min(6, len(self.history) - 1)
        recent = np.stack(self.history[-k:])  # [k, N, 2]
        close = np.linalg.norm(recent - self.history[-1][None], axis=2) < BORDER_EPS_M
        return close.sum(axis=0) > 2

    def cells(self) -> np.ndarray:
        """Each robot's cell [N, 2] int (rounded position)."""
        return robot_cells(self.positions_m)

    def neighbours(self) -> np.ndarray:
        """Communication graph [N, N] bool: distance < r_c (:func:`madp.sim.rules.closer_than`), no self
        loops (the true state)."""
        x = self.positions_m
        return closer_than(x[:, None] - x[None], self.params.comm_radius_m) & ~np.eye(self.num_robots, dtype=bool)

    def estimates_m(self) -> np.ndarray:
        """[N, 2]: each robot's estimate of its own position (the true one without position noise)."""
        return self._estimates

    def alive(self) -> np.ndarray:
        """[N] bool: the robots still running (all of them without a network)."""
        return np.ones(self.num_robots, bool) if self.network is None else self.network.alive(self.steps)

    def neighbour_view(self) -> tuple[np.ndarray, np.ndarray]:
        """What each robot knows of the others: ``known [N, N]`` bool (robot i holds a position of robot
        j within r_c of its own estimate; never i = j) and ``positions_m [N, N, 2]`` (the position it
        holds; its own estimate at [i, i]). Without a network: the true neighbours and positions."""
        if self._received is None:
            n = self.num_robots
            return self.neighbours(), np.broadcast_to(self.positions_m[None], (n, n, 2))
        own, rec = self._estimates, self._received
        held = rec.payload.copy()
        held[np.arange(self.num_robots), np.arange(self.num_robots)] = own
        return rec.valid & within_reach(own, held, self.params.comm_radius_m), held

    def beacons(self) -> list[list[Message]]:
        """The position beacons each robot's radio holds at this step, ``Message(sender, step sent,
        position)`` ascending by sender: over a network, what its ``position`` channel holds (lost
        ones missing, kept ones older); without one, every other robot's current true position (the
        robot keeps those within r_c: :meth:`neighbour_view`)."""
        n = self.num_robots
        if self._received is None:
            return [[Message(j, self.steps, self.positions_m[j].copy()) for j in range(n) if j != i] for i in range(n)]
        return self._received.messages()

    def sensor_readings(self) -> list[SensorReading]:
        """Robot i's sensor reading at this step, the one its map got (:meth:`RobotMaps.read` at its
        true cell)."""
        lo, values = self.maps.read(self.cells())
        return [SensorReading(lo[i], values[i]) for i in range(self.num_robots)]

    def local_maps(self) -> np.ndarray:
        """Raw 256 × 256 crops of each robot's own map [N, S, S] float32."""
        return self.maps.local_maps(self.cells())

    def observations(self) -> np.ndarray:
        """O [N, 4, 32, 32] float32, channels (local map, comm x, comm y, boundary): each robot's own map
        and the border around its (estimated) position, its neighbours from :meth:`neighbour_view`."""
        p = self.params
        if self.network is None:
            return self.maps.observations(self.positions_m, p.comm_radius_m, p.obs_size)
        return self.maps.observations(self.estimates_m(), p.comm_radius_m, p.obs_size, view=self.neighbour_view())

    def cost(self) -> float:
        """Coverage cost J of the current positions of the running robots on the world map."""
        if self.network is not None and self.network.failed.any():
            return coverage_cost(self.prefix, self.positions_m[self.alive()])
        return coverage_cost(self.prefix, self.positions_m)

    def normalized_cost(self) -> float:
        """J(t) / J(0)."""
        return self.cost() / self.cost0
