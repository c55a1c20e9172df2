"""Standard RL interfaces to madp's coverage world (optional extra ``madp[envs]``).

- :mod:`madp.envs.coverage_v0`: PettingZoo (``parallel_env()``, ``env()``), one agent per robot.
- ``gymnasium.make("madp/Coverage-v0")``: a centralized single-agent view (registered on import).
"""

from . import coverage_v0

__all__ = ["coverage_v0"]
