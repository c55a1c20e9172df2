"""A selection rule of your own: one record and one function. MADP draws K samples per robot and keeps
one; this rule ranks them as ``explore`` does, on the robot's own map with its unexplored blocks at the
mean importance of its explored ones, but counts that mean at half, so a robot looks less and covers
more of what it has found."""

from dataclasses import replace

import numpy as np

from madp.controllers import make_controller
from madp.policies import SamplingSettings
from madp.policies.select import select_actions
from madp.robot.choice import map_prior
from madp.selection import RULES, Rule
from madp.sim import CoverageEnv, Scenario, rollout


def half_explore(maps, views, predict):
    """The map the robot's local cell cost is summed on: its sensed map, plus half the explored mean on
    each block of its window it has not explored (rows: robots; ``predict``: a learned prior, unused)."""
    full = map_prior(maps, views)  # its sensed map with the mean on the unexplored blocks
    return replace(full, weights=views.weights + 0.5 * (full.weights - views.weights))


# The record: its name, one line of help, what it reads, its function. In madp itself it is one more
# line of RULES in madp/selection.py; the command line's help and the table of rules follow from it.
RULES["half_explore"] = Rule("half_explore", "explore, with half the explored mean on unexplored blocks", "own map",
                             half_explore)

env = CoverageEnv(Scenario.random(seed=0))
candidates = np.random.default_rng(0).normal(0.0, 2.0, (4, env.num_robots, 2))  # K = 4 samples per robot, m/s
kept = select_actions("half_explore", env, candidates)  # the same chooser the robot runtime calls
assert all(any(np.array_equal(kept[i], c) for c in candidates[:, i]) or not env.neighbour_view()[0][i].any()
           for i in range(env.num_robots))  # each robot keeps one of its samples (one that hears no one: its own step)

madp = make_controller("madp", sampling=SamplingSettings(select="half_explore", candidates=4))
result = rollout(CoverageEnv(Scenario.random(seed=0)), madp, steps=5)
print(f"MADP, half_explore among K = 4: J(5)/J(0) = {result.normalized_cost[-1]:.3f}")
assert result.normalized_cost[-1] < 1.0
