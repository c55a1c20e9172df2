"""What the PettingZoo and the Gymnasium environments share: construction from a scenario, episodes,
the shared reward, ``infos`` and ``render()``. Each environment adds its own spaces and API."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from madp.errors import SettingError
from madp.render import FrameRenderer
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.network import NetworkSettings

DEFAULT_MAX_STEPS = 600
RENDER_MODES = ["rgb_array"]


def resolve_scenario(scenario) -> Scenario | None:
    """A :class:`Scenario`, a scenario file path, or anything with ``.scenario()`` (a suite EnvSpec)."""
    if scenario is None or isinstance(scenario, Scenario):
        return scenario
    if isinstance(scenario, (str, Path)):
        return Scenario.load(scenario)
    if hasattr(scenario, "scenario"):
        return scenario.scenario()
    raise TypeError(f"scenario: expected a Scenario, a path or a suite EnvSpec, got {type(scenario).__name__}")


def episode_scenario(fixed: Scenario | None, params: SimParams, seed: int | None, rng: np.random.Generator) -> Scenario:
    """The scenario of the next episode: ``fixed`` if given, else ``Scenario.random(seed)`` (a seed
    drawn from ``rng`` when ``seed`` is None), so ``reset(seed=s)`` replays madp's scenario of seed s."""
    if fixed is not None:
        return fixed
    draw = int(seed) if seed is not None else int(rng.integers(0, 2**62))
    return Scenario.random(draw, params)


def map_bounds(params: SimParams) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel bounds of the [4, S, S] map tensor: maps in [0, 1]; neighbour channels are sums of
    r / r_c over at most N−1 neighbours, so in [−(N−1), N−1]."""
    s, k = params.obs_size, max(params.num_robots - 1, 1)
    low = np.zeros((4, s, s), dtype=np.float32)
    high = np.ones((4, s, s), dtype=np.float32)
    low[1:3], high[1:3] = -k, k
    return low, high


class CoverageWorld:
    """The coverage world behind an environment (mixed into both; see :mod:`madp.envs.coverage_v0`).

    ``self.sim`` is the :class:`CoverageEnv` of the current episode; ``self.trail`` every robot's
    positions since the reset, ``[t+1, N, 2]`` (for the trails of ``render()``).
    """

    def _configure(self, scenario, params: SimParams | None, max_steps: int, render_mode: str | None,
                   render_size: int, network: NetworkSettings | None = None) -> int:
        """Check and store the constructor's arguments; returns the number of robots. ``network``: the
        network between the robots (:mod:`madp.sim.network`; default: a suite EnvSpec's own, else none)."""
        self.network = network if network is not None else getattr(scenario, "network", None)
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise SettingError("render_mode", f"expected one of {RENDER_MODES} or None, got {render_mode!r}")
        if max_steps < 1:
            raise SettingError("max_steps", message=f"max_steps must be >= 1, got {max_steps}")
        self.scenario = resolve_scenario(scenario)
        self.params = self.scenario.params if self.scenario is not None else (params or SimParams())
        self.max_steps, self.render_mode, self.render_size = int(max_steps), render_mode, int(render_size)
        self.sim: CoverageEnv | None = None
        self._renderer: FrameRenderer | None = None
        return self.params.num_robots if self.scenario is None else len(self.scenario.robots_m)

    def _begin(self, seed: int | None, rng: np.random.Generator) -> None:
        """Start an episode (the fixed scenario again, or the one of ``seed`` / drawn from ``rng``)."""
        scenario = episode_scenario(self.scenario, self.params, seed, rng)
        if self.sim is None or self.sim.scenario is not scenario:
            self.sim = CoverageEnv(scenario, network=self.network)
            self._renderer = None
        else:
            self.sim.reset()
        self._cost = self.sim.cost()
        self._trail = [self.sim.positions_m.copy()]

    def _advance(self, u: np.ndarray) -> float:
        """Step the world with velocities ``u [N, 2]``; returns the reward (J(t−1) − J(t)) / J(0)."""
        self.sim.step(u)
        cost = self.sim.cost()
        reward = float((self._cost - cost) / self.sim.cost0)
        self._cost = cost
        self._trail.append(self.sim.positions_m.copy())
        return reward

    @property
    def truncated(self) -> bool:
        return self.sim.steps >= self.max_steps

    @property
    def trail(self) -> np.ndarray:
        return np.stack(self._trail)

    def _info(self) -> dict:
        return {"normalized_cost": float(self._cost / self.sim.cost0), "step": int(self.sim.steps)}

    def render(self):
        """``rgb_array``: the frame of :mod:`madp.render` (map, Voronoi cells, trails, robots, step and
        J(t)/J(0)), the same as frame t of ``madp rollout --video``."""
        if self.render_mode is None or self.sim is None:
            return None
        if self._renderer is None:
            self._renderer = FrameRenderer(self.sim.world_map, self.render_size)
        return self._renderer(self.sim.positions_m, self.trail, self.sim.steps, self._cost / self.sim.cost0)
