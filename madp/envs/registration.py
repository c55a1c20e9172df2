"""Registers ``madp/Coverage-v0`` (:class:`madp.envs.gym_coverage.CoverageGymEnv`) with Gymnasium,
once per process; importing :mod:`madp.envs` does it."""

import gymnasium

GYM_ID = "madp/Coverage-v0"

if GYM_ID not in gymnasium.registry:
    gymnasium.register(id=GYM_ID, entry_point="madp.envs.gym_coverage:CoverageGymEnv")
