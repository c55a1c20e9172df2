"""Standard RL interfaces to madp's coverage world (optional extra ``madp[envs]``).

- :mod:`madp.envs.coverage_v0`: PettingZoo (``parallel_env()``, ``env()``), one agent per robot.
- ``gymnasium.make("madp/Coverage-v0")``: a centralized single-agent view
  (:class:`madp.envs.gym_coverage.CoverageGymEnv`), registered on import of this package (:mod:`.registration`).
"""

from madp.controllers import make_controller

from . import coverage_v0
from .registration import GYM_ID

__all__ = ["GYM_ID", "coverage_v0", "make_controller"]
