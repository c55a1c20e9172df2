"""The coverage world: importance map, robots, sensing, Voronoi sums, cost J, observations and the
classical controllers. numpy/scipy and numba kernels for the hot paths (``kernels.py``; no torch), so it
imports fast and runs anywhere."""

from .controllers import ClairvoyantCVT, Controller, DecentralizedCVT, lloyd_velocity
from .env import CoverageEnv
from .idf import importance_map, random_features
from .observations import observation_tensor, resize_matrix
from .params import SimParams
from .rollout import Rollout, rollout
from .scenario import Scenario, ScenarioError
from .voronoi import CellSums, ColumnPrefix, coverage_cost, voronoi_sums

__all__ = [
    "CellSums", "ClairvoyantCVT", "ColumnPrefix", "Controller", "CoverageEnv",
    "DecentralizedCVT", "Rollout", "Scenario", "ScenarioError", "SimParams", "coverage_cost",
    "importance_map", "lloyd_velocity", "observation_tensor", "random_features",
    "resize_matrix", "rollout", "voronoi_sums",
]
