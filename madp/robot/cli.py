"""``madp-robot``: the command line of a robot (the ``madp-robot`` distribution, ``robot/pyproject.toml``;
a dev install of madp has it too). Standard library argparse only: it imports no torch and no typer.

- ``madp-robot step --export DIR [--seed S]``: loads the export ``DIR`` (``madp export``), runs one
  control step of robot 0 on a synthetic input made from the seed alone (a position in the middle half
  of the world, a sensor reading of uniform importances, an empty inbox) and prints one JSON line
  ``{"action_mps": [vx, vy], "rule": ..., "seed": S}`` (m/s, world axes): the check that the robot's
  installation runs the policy.
- ``madp-robot run ARGS...``: one robot process of a swarm; the arguments go to
  :func:`madp.robot.process.main` unchanged.

As ``madp``'s (:mod:`madp.commands.main`): a user's mistake (a bad flag, a :class:`madp.errors.MadpError`,
an ``OSError``, a package madp-robot depends on that is not installed) is one line ``madp-robot: error: …``
on stderr and exit status 2 (``MADP_DEBUG=1`` raises it instead); anything else is a bug: the traceback,
one line asking for a report, exit status 1.
``python -m madp.robot`` runs the same command line.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import traceback
from typing import Callable, Sequence

from madp.errors import MadpError
from madp.sampling import sampling_help

__all__ = ["main", "step_action"]

PROG = "madp-robot"


class _UsageError(Exception):
    """A bad command line (argparse's complaint)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, as every other mistake, instead of usage + message
        raise _UsageError(message)


def _parser() -> _Parser:
    parser = _Parser(prog=PROG, description="The robot side of madp: run an exported MADP policy on a robot.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    step = sub.add_parser("step", help="one control step on a synthetic input: checks an installation and an export",
                          description="Load the export DIR, run one control step of robot 0 on a synthetic input "
                                      "made from the seed and print its action (m/s) as one JSON line.")
    step.add_argument("--export", required=True, metavar="DIR", help="the directory madp export wrote")
    step.add_argument("--seed", type=int, default=0, metavar="S", help="the episode's seed and the input's (default 0)")
    step.add_argument("--sampling", default=None, metavar="SPEC", help=sampling_help("The export fixes sampler, steps "
                      "and precision; its rule, k and frame may change here."))
    sub.add_parser("run", add_help=False, help="one robot process of a swarm (madp-robot run --help)")
    return parser


def step_action(export_dir: str, seed: int = 0, sampling: str | None = None) -> dict:
    """Robot 0's control step 0 of the episode of ``seed`` with the policy exported to ``export_dir`` on
    a synthetic input drawn from ``seed``: its position uniform in the middle half of the world, its
    sensor's reading uniform importances in [0, 1) around it, no message received. Returns
    ``{"action_mps": [vx, vy], "rule": selection rule, "seed": seed}``."""
    import numpy as np

    from madp.errors import SettingError
    from madp.robot.agent import RobotAgent, SensorReading
    from madp.robot.runtime import RobotRuntime
    from madp.sim.robot_maps import robot_cells

    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 1 << 63:
        raise SettingError("seed", f"expected a whole number from 0 to 2**63 - 1, got {seed!r}")
    runtime = RobotRuntime(export_dir, sampling=sampling)
    params = runtime.params
    rng = np.random.default_rng(seed)
    position_m = rng.uniform(0.25, 0.75, 2) * runtime.world_size_m
    s = params.sensor_size
    reading = SensorReading(robot_cells(position_m[None])[0] - s // 2, rng.random((s, s), dtype=np.float32))
    agent = RobotAgent(0, runtime, params, seed)
    agent.observe(0, position_m, reading)
    agent.token([])
    result = agent.act([])
    return {"action_mps": [float(v) for v in result.action_mps], "rule": runtime.rule, "seed": seed,
            "sampling": runtime.sampling_spec, "noise": "robot"}


def _run(argv: list[str]) -> int:
    """``madp-robot run``: :func:`madp.robot.process.main` on ``argv``."""
    from madp.robot.process import main as process_main  # zenoh and the agent: only when asked for

    return int(process_main(list(argv)) or 0)


def _user_error(e: Exception) -> str | None:
    """The one line a user's mistake prints, or None when ``e`` is a bug in madp."""
    if isinstance(e, ModuleNotFoundError):  # a package madp-robot depends on; a missing madp module is a bug
        return None if (e.name or "madp").split(".")[0] == "madp" else f"{e}: install madp-robot's dependencies"
    if isinstance(e, (_UsageError, MadpError, OSError)):
        return " ".join((str(e) or type(e).__name__).split())
    return None


def _guarded(action: Callable[[], int]) -> int:
    """``action()``'s exit status, with the errors as the module docstring says."""
    try:
        return action()
    except KeyboardInterrupt:
        sys.stderr.write(f"{PROG}: interrupted\n")
        return 130
    except Exception as e:
        line = _user_error(e)
        if line is None:
            traceback.print_exc()
            sys.stderr.write(f"{PROG}: internal error: this is a bug in madp, not a mistake in the command; please "
                             "report it with the command line and the traceback above\n")
            return 1
        if os.environ.get("MADP_DEBUG"):
            raise
        sys.stderr.write(f"{PROG}: error: {line}\n")
        return 2


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``madp-robot`` on ``argv`` (default: the process's arguments); returns the exit status."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] == ["run"]:  # everything after it is the robot process's, --help included
        return _guarded(lambda: _run(args[1:]))
    parser = _parser()

    def action() -> int:
        ns = parser.parse_args(args)
        if ns.command is None:
            parser.print_help()
            return 2
        print(json.dumps(step_action(ns.export, ns.seed, ns.sampling)), flush=True)
        return 0

    return _guarded(action)
