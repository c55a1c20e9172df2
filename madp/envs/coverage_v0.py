"""``coverage_v0``: madp's coverage world as a PettingZoo environment, one agent per robot.

    from madp.envs import coverage_v0
    env = coverage_v0.parallel_env(seed=0)          # or scenario=Scenario / "file.json" / suite EnvSpec
    obs, infos = env.reset(seed=0)

- **Agents** ``robot_0 … robot_{N-1}``, all live for the whole episode.
- **Observation** (``Dict``), what a decentralized robot knows, the same as madp's learned policies see:
  ``maps`` [4, 32, 32] float32 (local map, neighbours' x, neighbours' y, boundary; see
  :mod:`madp.sim.observations`); ``position`` [2] (m); ``neighbours`` [N-1, 2] relative positions
  x_j − x_i (m) of the robots within r_c, nearest first, zero-padded; ``neighbour_mask`` [N-1]
  (1 where a row is a real neighbour).
- **Action** velocity ``Box(-u_max, u_max, (2,))`` m/s (u_max = 5 by default); the simulator clips the
  speed |u| to u_max, as for every madp controller. A live agent missing from the action dict stands still.
- **Reward** shared by all robots: the decrease of normalised coverage cost, (J(t−1) − J(t)) / J(0). It is
  dense, scale-free across maps, and sums over an episode to 1 − J(T)/J(0), madp's headline metric.
- **Termination** never; **truncation** of every agent after ``max_steps`` (default 600) steps.
- **Scenario**: the given one at every reset, or, when none is given, ``Scenario.random(seed)`` drawn
  at each reset (seed from ``reset(seed=…)``, else from the env's generator), with ``params``.
- ``render_mode="rgb_array"``: the map, Voronoi cells, trails, robots, step and J(t)/J(0) (:mod:`madp.render`;
  the frames of ``madp rollout --video``), ``render_size`` pixels square.
- ``infos[agent]["normalized_cost"]`` is J(t)/J(0).
- Any madp controller drives it: ``env.step(env.actions_from(make_controller("madp")))``
  (:func:`madp.controllers.make_controller`; the world is ``env.sim``, a :class:`CoverageEnv`).
"""

from __future__ import annotations

import functools

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv
from pettingzoo.utils import parallel_to_aec

from madp.sim.network import NetworkSettings
from madp.sim import SimParams
from madp.sim.rules import closer_than, distances_m

from .base import DEFAULT_MAX_STEPS, RENDER_MODES, CoverageWorld, map_bounds

__all__ = ["CoverageParallelEnv", "DEFAULT_MAX_STEPS", "env", "neighbour_table", "parallel_env", "raw_env"]


def agent_observation_space(params: SimParams) -> spaces.Dict:
    k, rc, w = max(params.num_robots - 1, 1), float(params.comm_radius_m), float(params.world_size)
    low, high = map_bounds(params)
    return spaces.Dict({
        "maps": spaces.Box(low, high, dtype=np.float32),
        "position": spaces.Box(0.0, w, (2,), dtype=np.float32),
        "neighbours": spaces.Box(-rc, rc, (k, 2), dtype=np.float32),
        "neighbour_mask": spaces.MultiBinary(k),
    })


def neighbour_table(positions_m: np.ndarray, comm_radius_m: float,
                    view: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Padded relative positions [N, K, 2] (nearest first) and mask [N, K] int8, K = max(N−1, 1), of each
    robot's neighbours within r_c: from the robots' ``positions_m`` [N, 2], or, with ``view`` = (known
    [N, N], held [N, N, 2]) (:meth:`madp.sim.CoverageEnv.neighbour_view`), from what each robot holds."""
    n = len(positions_m)
    k = max(n - 1, 1)
    held = positions_m[None, :, :] if view is None else view[1]
    rel = held - positions_m[:, None, :]  # [i, j, 2] = x_j - x_i
    dist = distances_m(rel)
    near = closer_than(rel, comm_radius_m) & ~np.eye(n, dtype=bool)
    if view is not None:
        near &= view[0]
    key = np.where(near, dist, np.inf)
    key[np.arange(n), np.arange(n)] = np.inf
    order = np.argsort(key, axis=1, kind="stable")[:, :k]  # neighbours first, nearest first
    mask = np.take_along_axis(near, order, axis=1)
    table = np.take_along_axis(rel, order[:, :, None], axis=1) * mask[:, :, None]
    if n == 1:
        table, mask = np.zeros((1, 1, 2)), np.zeros((1, 1), dtype=bool)
    bound = np.float32(comm_radius_m)
    return np.clip(table.astype(np.float32), -bound, bound), mask.astype(np.int8)


class CoverageParallelEnv(CoverageWorld, ParallelEnv):
    """PettingZoo parallel coverage environment (see the module docstring)."""

    metadata = {"name": "coverage_v0", "render_modes": RENDER_MODES, "render_fps": 5, "is_parallelizable": True}

    def __init__(self, scenario=None, params: SimParams | None = None, max_steps: int = DEFAULT_MAX_STEPS,
                 render_mode: str | None = None, render_size: int = 512, seed: int | None = None,
                 network: NetworkSettings | None = None):
        n = self._configure(scenario, params, max_steps, render_mode, render_size, network)
        self.possible_agents = [f"robot_{i}" for i in range(n)]
        self.agents: list[str] = []
        self.np_random, self.np_random_seed = seeding.np_random(seed)
        self._obs_space = agent_observation_space(self.params)
        u = float(self.params.max_speed_mps)
        self._act_space = spaces.Box(-u, u, (2,), dtype=np.float32)

    # spaces are the same objects at every call, so seeding them (as PettingZoo's tests do) sticks
    @functools.lru_cache(maxsize=None)
    def observation_space(self, agent: str) -> spaces.Dict:
        return self._obs_space

    @functools.lru_cache(maxsize=None)
    def action_space(self, agent: str) -> spaces.Box:
        return self._act_space

    # --- episode -------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.np_random, self.np_random_seed = seeding.np_random(seed)
        self._begin(seed, self.np_random)
        self.agents = list(self.possible_agents)
        return self._observations(), self._infos()

    def step(self, actions: dict):
        if not self.agents:
            raise RuntimeError("step() called on a finished episode; call reset()")
        u = np.zeros((len(self.possible_agents), 2))
        for i, agent in enumerate(self.possible_agents):
            if actions.get(agent) is not None:
                u[i] = np.asarray(actions[agent], dtype=np.float64).reshape(2)
        reward = self._advance(u)
        obs, infos = self._observations(), self._infos()
        rewards = dict.fromkeys(self.agents, reward)
        terminations = dict.fromkeys(self.agents, False)
        truncations = dict.fromkeys(self.agents, self.truncated)
        if self.truncated:
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    def actions_from(self, controller) -> dict:
        """The actions of any madp controller (:mod:`madp.controllers`) as this env's action dict
        (float64, as the controller computed them, so the rollout equals madp's own loop bit for bit)."""
        u = controller(self.sim)
        return {a: u[i] for i, a in enumerate(self.possible_agents) if a in self.agents}

    # --- views ---------------------------------------------------------------------------------
    def _observations(self) -> dict:
        maps = self.sim.observations()
        own = self.sim.estimates_m()  # what each robot knows of itself and of the others
        table, mask = neighbour_table(own, self.params.comm_radius_m,
                                      self.sim.neighbour_view() if self.sim.network is not None else None)
        pos = own.astype(np.float32)
        return {a: {"maps": maps[i], "position": pos[i], "neighbours": table[i], "neighbour_mask": mask[i]}
                for i, a in enumerate(self.possible_agents)}

    def _infos(self) -> dict:
        return {a: self._info() for a in self.possible_agents}

    def state(self) -> np.ndarray:
        """Global state: positions [N, 2] (m)."""
        return self.sim.positions_m.copy()

    def close(self) -> None:
        pass


def parallel_env(**kwargs) -> CoverageParallelEnv:
    """The parallel form (see :class:`CoverageParallelEnv` for the arguments)."""
    return CoverageParallelEnv(**kwargs)


def raw_env(**kwargs):
    """The AEC form without PettingZoo's order-enforcing wrapper (as PettingZoo's environments name it)."""
    return parallel_to_aec(parallel_env(**kwargs)).env


def env(**kwargs):
    """The AEC form (agents act in turn; the world steps once all have acted)."""
    return parallel_to_aec(parallel_env(**kwargs))
