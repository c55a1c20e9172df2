"""A batch of environments stepped side by side on threads (madp/sim/rollout.py): the costs, positions
and maps are those of stepping them one after another, bit for bit, with and without a network; the
default thread count follows the process's torch setting (numba's without torch); an error in one
environment's step is raised after every environment has stepped."""

from __future__ import annotations

import copy
import sys

import numba
import numpy as np
import pytest

from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.controllers import DecentralizedCVT
from madp.sim.network import NetworkSettings
from madp.sim.rollout import Costs, Positions, env_threads, for_each_env, run, step_threads
from tests.conftest import one_torch_thread

PARAMS = SimParams(world_size=512, num_robots=8, num_features=6)


def _batch() -> list[CoverageEnv]:
    lossy = NetworkSettings(loss=0.3, position_noise_m=1.0, seed=2)
    return [CoverageEnv(Scenario.random(s, PARAMS), network=lossy if s % 2 else None) for s in range(5)]


def _rollout(envs: list[CoverageEnv], threads: int, steps: int = 12):
    costs, positions = Costs(steps), Positions(steps)
    dcvt = DecentralizedCVT()
    run(envs, lambda es: np.stack([dcvt(e) for e in es]), [costs, positions], steps, threads=threads)
    return costs.cost, positions.positions_m


@pytest.mark.parametrize("threads", [2, 3, 8])
def test_threads_step_the_batch_as_one_after_another(threads):
    base = _batch()
    one, many = copy.deepcopy(base), copy.deepcopy(base)
    want, got = _rollout(one, 1), _rollout(many, threads)
    assert all(np.array_equal(a, b) for a, b in zip(want, got))
    for a, b in zip(one, many):
        assert np.array_equal(a.maps.maps_padded, b.maps.maps_padded)
        assert np.array_equal(a.maps.explored, b.maps.explored)
        assert a.steps == b.steps == 12
    alone = copy.deepcopy(base[3])  # the batch's environment 3 rolled out by itself
    cost, pos = _rollout([alone], 1)
    assert np.array_equal(cost[0], want[0][3]) and np.array_equal(pos[0], want[1][3])


def test_the_default_thread_count_is_the_processs_setting(monkeypatch):
    import torch

    with one_torch_thread():
        assert step_threads() == 1  # madp eval's workers: one environment after another
    before = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        assert step_threads() == 3
    finally:
        torch.set_num_threads(before)
    monkeypatch.delitem(sys.modules, "torch")  # a process without torch (the robot wheel)
    assert step_threads() == numba.get_num_threads()


@pytest.mark.parametrize("threads", [1, 3])
def test_an_error_in_one_environment_is_raised_after_every_one_stepped(threads):
    envs = _batch()[:4]
    u = list(np.zeros((4, PARAMS.num_robots, 2)))
    u[1][0, 0] = np.nan
    u[2] = np.zeros((3, 2))  # a later error: "actions must have shape ..."
    with env_threads(len(envs), threads):
        with pytest.raises(ValueError, match="^actions contain NaN or infinity$"):
            for_each_env(lambda e, x: e.step(x), envs, u)
    assert [e.steps for e in envs] == [1, 0, 0, 1]
    with pytest.raises(ValueError, match="threads must be >= 1, got 0"):
        run(envs, lambda es: u, steps=1, threads=0)
