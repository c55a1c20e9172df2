"""The one rollout loop: controllers act on environments, hooks record what their caller wants.

:func:`run` steps B environments in lockstep (B = 1 for a lone rollout). At every control step t it
asks ``act(envs) -> actions [B, N, 2]`` (m/s) for the state at t, shows them to the hooks, and steps
each environment with them (or with ``drive(envs, actions)``, what relabelling datagen executes
instead). Hooks see the state at t = 0 (:meth:`Hook.start`), the actions at every step with the wall
time ``act`` took (:meth:`Hook.actions`; a hook may end the rollout there, before those actions are
executed) and the state after every step (:meth:`Hook.stepped`). ``madp rollout`` (:func:`rollout`),
``madp eval`` (one environment or a batch) and ``madp datagen`` (expert and learner) all run this loop
with their own hooks; the hooks here record cost curves, positions, actions, samples and timing
(frames for videos: :class:`madp.video.Frames`).

The environments of a batch step side by side on threads (:func:`step_threads` of them by default,
at most one per environment): a step's work is in numba kernels that release the GIL, and each
environment's step reads and writes its own state alone, so the results are those of stepping them
one after another, bit for bit. Hooks may do their own work per environment on the same threads
(:func:`for_each_env`, as :class:`Costs` does).
"""

from __future__ import annotations

import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor, wait
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence, TypeVar

import numba
import numpy as np

from .controllers import Controller
from .env import CoverageEnv

#: ``act(envs) -> actions [B, N, 2]`` m/s for the current state of each environment.
Act = Callable[[list[CoverageEnv]], np.ndarray]


class Hook:
    """What a caller records of a rollout. Every method is optional; the defaults do nothing."""

    def start(self, envs: list[CoverageEnv]) -> None:
        """The state at t = 0."""

    def actions(self, t: int, envs: list[CoverageEnv], actions: np.ndarray, act_s: float) -> bool | None:
        """The actions ``[B, N, 2]`` for the state at step t, computed in ``act_s`` seconds. Return True
        to end the rollout here, before they are executed."""

    def stepped(self, t: int, envs: list[CoverageEnv]) -> None:
        """The state at step t (t >= 1), after the environments stepped."""


def act_alone(controller: Controller) -> Act:
    """``act`` of one controller on one environment."""
    return lambda envs: controller(envs[0])[None]


def step_threads() -> int:
    """How many threads :func:`run` steps a batch of environments on by default: the process's torch
    intra-op threads where torch is loaded (1 in ``madp eval``'s worker processes, which leave the
    cores to each other), numba's thread count otherwise."""
    torch = sys.modules.get("torch")
    return max(1, int(torch.get_num_threads())) if torch is not None else max(1, numba.get_num_threads())


T = TypeVar("T")
_POOL: ContextVar[ThreadPoolExecutor | None] = ContextVar("madp_rollout_pool", default=None)


@contextmanager
def env_threads(num_envs: int, threads: int | None = None) -> Iterator[None]:
    """While inside, :func:`for_each_env` runs on min(``threads``, ``num_envs``) threads
    (``threads`` None: :func:`step_threads`); on the caller's thread alone when that is 1."""
    if threads is not None and int(threads) < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    n = min(num_envs, step_threads() if threads is None else int(threads))
    if n <= 1:
        token = _POOL.set(None)
        try:
            yield
        finally:
            _POOL.reset(token)
        return
    with ThreadPoolExecutor(n, thread_name_prefix="madp-env") as pool:
        token = _POOL.set(pool)
        try:
            yield
        finally:
            _POOL.reset(token)


def for_each_env(fn: Callable[..., T], envs: Sequence[CoverageEnv], args: Sequence | None = None) -> list[T]:
    """``[fn(env) for env in envs]`` (``[fn(env, arg) for env, arg in zip(envs, args)]`` with
    ``args``), on the threads of the :func:`env_threads` in effect (one after another outside one).
    ``fn`` must touch only its own environment's state. Every call runs even when one raises, on
    threads or not; then the first error in the environments' order is raised."""
    pool = _POOL.get()
    calls = list(zip(envs)) if args is None else list(zip(envs, args))
    if pool is None:
        futures = [_called(fn, c) for c in calls]
    else:
        futures = [pool.submit(fn, *c) for c in calls]
        wait(futures)
    return [f.result() for f in futures]


def _called(fn: Callable[..., T], args: tuple) -> Future:
    """``fn(*args)`` called here, as a done future (its result or its error)."""
    done: Future = Future()
    try:
        done.set_result(fn(*args))
    except Exception as e:  # kept for the caller, who raises the first one
        done.set_exception(e)
    return done


def _step(env: CoverageEnv, actions_mps: np.ndarray) -> None:
    env.step(actions_mps)


def run(envs: list[CoverageEnv], act: Act, hooks: Sequence[Hook] = (), steps: int | None = None,
        drive: Callable[[list[CoverageEnv], np.ndarray], np.ndarray] | None = None, threads: int | None = None) -> int:
    """Step ``envs`` from their current state with ``act`` for ``steps`` control steps (None: until a
    hook ends the rollout). ``drive``: what the environments execute instead of the actions (default:
    the actions). ``threads``: how many environments step at once (None: :func:`step_threads`; the
    results do not depend on it). Returns the number of steps taken."""
    with env_threads(len(envs), threads):
        for h in hooks:
            h.start(envs)
        t = 0
        while steps is None or t < steps:
            t0 = time.perf_counter()
            u = act(envs)
            act_s = time.perf_counter() - t0
            if any([h.actions(t, envs, u, act_s) for h in hooks]):  # every hook sees the step
                break
            executed = u if drive is None else drive(envs, u)
            for_each_env(_step, envs, list(executed))
            t += 1
            for h in hooks:
                h.stepped(t, envs)
    return t


def _normalized_cost(env: CoverageEnv) -> float:
    return env.normalized_cost()


class Costs(Hook):
    """``cost [B, steps + 1]``: J(t)/J(0) of each environment (1 at t = 0)."""

    def __init__(self, steps: int):
        self.steps = steps

    def start(self, envs):
        self.cost = np.empty((len(envs), self.steps + 1))
        self.cost[:, 0] = 1.0

    def stepped(self, t, envs):
        self.cost[:, t] = for_each_env(_normalized_cost, envs)


class Positions(Hook):
    """``positions_m [len(which), steps + 1, N, 2]`` of the environments ``which`` (default: all)."""

    def __init__(self, steps: int, which: Sequence[int] | None = None):
        self.steps, self.which = steps, which

    def start(self, envs):
        self.which = list(range(len(envs))) if self.which is None else list(self.which)
        self.positions_m = np.empty((len(self.which), self.steps + 1, envs[0].num_robots, 2))
        self.stepped(0, envs)

    def stepped(self, t, envs):
        for j, i in enumerate(self.which):
            self.positions_m[j, t] = envs[i].positions_m


class Actions(Hook):
    """``actions_mps [B, steps, N, 2]``: what the controller chose at every step."""

    def __init__(self, steps: int):
        self.steps = steps

    def start(self, envs):
        self.actions_mps = np.empty((len(envs), self.steps, envs[0].num_robots, 2))

    def actions(self, t, envs, actions, act_s):
        self.actions_mps[:, t] = actions


class Timing(Hook):
    """``step_s [steps]``: the wall time of each control step's ``act``, divided by the batch size
    (the amortised cost per environment)."""

    def __init__(self, steps: int):
        self.step_s = np.empty(steps)

    def actions(self, t, envs, actions, act_s):
        self.step_s[t] = act_s / len(envs)


class Samples(Hook):
    """``samples_mps [steps, N, M, 2]`` (NaN between draws): every ``every``-th step, M extra actions
    of environment 0 drawn by ``draw(env) -> [M, N, 2]`` (e.g. a policy's own samples, with noise that
    leaves the rollout's alone)."""

    def __init__(self, steps: int, num_samples: int, every: int, draw: Callable[[CoverageEnv], np.ndarray]):
        self.steps, self.num_samples, self.every, self.draw = steps, num_samples, every, draw

    def start(self, envs):
        self.samples_mps = np.full((self.steps, envs[0].num_robots, self.num_samples, 2), np.nan)

    def actions(self, t, envs, actions, act_s):
        if t % self.every == 0:
            self.samples_mps[t] = self.draw(envs[0]).transpose(1, 0, 2)


class Links(Hook):
    """``links [steps + 1, N, N]`` int8: what happened on every link of environment 0's network at every
    step (``madp.sim.network.Network.links``: delivered, lost, kept or nothing; receiver i, sender j)."""

    def __init__(self, steps: int):
        self.steps = steps

    def start(self, envs):
        n = envs[0].num_robots
        self.links = np.zeros((self.steps + 1, n, n), np.int8)
        self.stepped(0, envs)

    def stepped(self, t, envs):
        if envs[0].network is not None:
            self.links[t] = envs[0].network.links("position")


class Convergence(Hook):
    """``converged_at``: the first step t (1-based, as the library counts) whose actions were all zero
    (environment 0), or None."""

    converged_at: int | None = None

    def actions(self, t, envs, actions, act_s):
        if self.converged_at is None and not np.any(actions[0]):
            self.converged_at = t + 1


@dataclass
class Rollout:
    """normalized_cost [T+1] (J(t)/J(0), t = 0..T); positions_m [T+1, N, 2]; converged_at: the control
    step t (1-based, as the library counts) whose actions were all zero, or None if none was."""

    normalized_cost: np.ndarray
    positions_m: np.ndarray
    converged_at: int | None

    def to_json(self, controller: str) -> dict:
        return {
            "controller": controller,
            "steps": len(self.normalized_cost) - 1,
            "cost": [float(c) for c in self.normalized_cost],
            "positions": self.positions_m[-1].tolist(),
            "converged_at": self.converged_at,
        }


def rollout(env: CoverageEnv, controller: Controller, steps: int, hooks: Sequence[Hook] = ()) -> Rollout:
    """Reset ``env`` and run ``controller`` for ``steps`` steps (``hooks``: what else to record)."""
    env.reset()
    costs, positions, converged = Costs(steps), Positions(steps), Convergence()
    run([env], act_alone(controller), [costs, positions, converged, *hooks], steps)
    return Rollout(costs.cost[0], positions.positions_m[0], converged.converged_at)
