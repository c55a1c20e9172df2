"""``madp swarm``: one run of a swarm of robot processes (:mod:`madp.swarm.world`) into an output directory.

Everything the user chose is checked before a process starts (the scenario file, the export's
``runtime.json`` and graphs, the steps up to :data:`MAX_STEPS`, the rate within :data:`RATE_HZ`, the
robots this machine holds: :func:`madp.swarm.robots.check_capacity`, the output directory), each a
one-line error. The directory is locked for the run (:func:`madp.io.lock.locked_dir`); it must be
empty, or hold an earlier ``madp swarm`` run that ``overwrite`` replaces: the files its record
:data:`RECORD` lists (:func:`madp.io.owned.clear_owned`: any other file makes it refuse, a
``summary.json`` without that record too). It receives the record first, then ``summary.json``
(:func:`run_swarm` says what it holds) and ``swarm.mcap`` (the rosbag2 log of :mod:`madp.robot.ros2`),
each written atomically.

A run whose robots have all failed ends at that step: its summary says so (``outcome``), and
:func:`run_swarm` raises a one-line :class:`madp.errors.MadpError` after writing it.
"""

from __future__ import annotations

import importlib.util
import json
import sys
import time
from pathlib import Path

from madp.errors import InputError, MadpError, SettingError
from madp.io.atomic import is_temp, remove_temps, write_json_atomic, write_text_atomic
from madp.io.lock import LOCK_FILENAME, locked_dir
from madp.io.owned import clear_owned
from madp.sim import Scenario
from madp.sim.network import NetworkSettings

from .world import BEACON_BY, COMMAND_BY, COST_BY, TOKEN_BY, World

__all__ = ["MAX_STEPS", "OWNED", "RATE_HZ", "RECORD", "run_swarm"]

#: The record of what a swarm run wrote in its directory (JSON: ``{"files": [...]}``), written first.
RECORD = "madp-swarm.json"
#: The files a swarm run writes in its directory.
OWNED = ("summary.json", "swarm.mcap", RECORD)
#: The most control steps of one run (a day at 1 Hz; the log grows with every step).
MAX_STEPS = 100_000
#: The rates (Hz) of real time: below, a step waits for minutes; above, a period is shorter than one
#: robot's control step, so every deadline is missed.
RATE_HZ = (0.01, 50.0)
#: Seconds between progress lines when the output is not a terminal.
LINE_EVERY_S = 30.0


def _recorded(out: Path) -> list[str]:
    """What an earlier run's record says it wrote in ``out`` (nothing without a readable record)."""
    try:
        files = json.loads((out / RECORD).read_text())["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    return [RECORD, *(f for f in files if f in OWNED)] if isinstance(files, list) else []


def _check_out(out: Path, overwrite: bool) -> None:
    """Refuse an output directory that holds anything but an earlier run (with ``overwrite``) or nothing."""
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: not a directory; choose another --out")
    if overwrite:
        clear_owned(out, _recorded(out))
        return
    present = sorted(p.name for p in out.iterdir() if p.name != LOCK_FILENAME and not is_temp(p))
    if present:
        what = ("an earlier madp swarm run: --overwrite replaces it" if set(present) <= set(_recorded(out))
                else "files madp swarm did not write")
        raise SettingError("out", f"{out}: not empty ({present[0]}{' ...' if len(present) > 1 else ''}; {what}); "
                                  "choose another --out")


def check_run(steps, rate_hz) -> None:
    """One-line errors for ``steps`` outside 1..:data:`MAX_STEPS` and ``rate_hz`` outside :data:`RATE_HZ`."""
    if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= MAX_STEPS:
        raise SettingError("steps", f"expected a whole number of steps from 1 to {MAX_STEPS}, got {steps!r}")
    lo, hi = RATE_HZ
    if rate_hz is not None and not (isinstance(rate_hz, (int, float)) and lo <= rate_hz <= hi):
        raise SettingError("rate_hz", f"expected a rate from {lo} to {hi} Hz (a step's period from {1 / hi:.2f} s "
                                      f"to {1 / lo:.0f} s), got {rate_hz!r}")


class _Progress:
    """Steps done, steps/s and J(t)/J(0): a rich bar on a terminal, else a line every LINE_EVERY_S."""

    def __init__(self, total: int, enabled: bool, started: str):
        self.total, self.enabled, self.tty = total, enabled, enabled and sys.stderr.isatty()
        self.t0 = self.last = time.perf_counter()
        if enabled and not self.tty:
            print(f"swarm 0/{total}: {started}", flush=True)
        if self.tty:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(TextColumn("swarm"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                                TimeElapsedColumn())
            self.bar.start()
            self.task = self.bar.add_task("swarm", total=total, info="")

    def update(self, done: int, cost: float) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        info = f"{done / max(now - self.t0, 1e-9):.2f} steps/s  J/J0 {cost:.4f}"
        if self.tty:
            self.bar.update(self.task, completed=done, info=info)
        elif now - self.last >= LINE_EVERY_S or done == self.total:
            print(f"swarm {done}/{self.total}: {info}", flush=True)
            self.last = now

    def close(self) -> None:
        if self.tty:
            self.bar.stop()
            self.tty = False


def run_swarm(scenario: str | Path, export: str | Path, steps: int, out: str | Path,
              network: NetworkSettings | None = None, rate_hz: float | None = None, overwrite: bool = False,
              progress: bool = True, secret: bytes | None = None, sampling: str | None = None) -> dict:
    """Run the scenario's swarm, one robot process per robot with the policy exported to ``export``, for
    ``steps`` control steps over ``network`` (ideal when None), in lockstep or at ``rate_hz``; write
    ``out/summary.json`` and ``out/swarm.mcap`` and return the summary: ``final_cost`` (J(T)/J(0)),
    ``cost`` (J(t)/J(0), t = 0..T), per robot its ``pid``, step latency ``latency_ms`` p50/p99 (from its
    STEP packet sent to its command received), ``deadline_misses``, ``failed_at_step`` (or null) and its
    messages sent, delivered and their bytes per channel; the records dropped (``dropped``: forged,
    malformed, foreign); the run's settings (its sampling as a spec, ``sampling``: the export's rule, K or
    frame changed for every robot, :func:`madp.sampling.parse_sampling`) and timings; ``outcome``
    (``completed``, or why it ended early). ``secret``: the run's (:mod:`madp.robot.seal`; default a fresh one)."""
    from madp.robot.ros2 import RosbagWriter
    from madp.robot.runtime import RobotRuntime

    from .bus import WorldBus
    from .robots import RobotProcesses, check_capacity

    missing = [pkg for mod, pkg in (("zenoh", "eclipse-zenoh"), ("onnxruntime", "onnxruntime"), ("mcap_ros2", "mcap-ros2-support"))
               if importlib.util.find_spec(mod) is None]
    if missing:
        raise MadpError(f"madp swarm needs {', '.join(missing)}, which is not installed (pip install {' '.join(missing)})")
    check_run(steps, rate_hz)
    sc, out, net = Scenario.load(scenario), Path(out), network or NetworkSettings()
    check_capacity(len(sc.robots_m))
    runtime = RobotRuntime(export, sampling=sampling)  # checks runtime.json, the graphs, the spec: one line naming it
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: not a directory; choose another --out")
    p, seed = sc.params, sc.seed if sc.seed is not None else 0
    with locked_dir(out):
        _check_out(out, overwrite)
        remove_temps(out)
        write_text_atomic(out / RECORD, json.dumps({"files": list(OWNED)}) + "\n")
        bus = WorldBus(len(sc.robots_m), secret=secret)
        robots = log = None
        try:
            meta = {"scenario": json.dumps(sc.to_dict()), "steps": steps, "dt_s": p.dt_s, "seed": seed,
                    "controller": "madp", "runtime": "swarm", "network": net.as_dict(), "rate_hz": rate_hz}
            log = RosbagWriter(out / "swarm.mcap", p.dt_s, meta)
            world = World(sc, bus, runtime.token_dim, net, rate_hz, log, runtime.candidates if runtime.joint else None)
            robots = RobotProcesses(world.n, export, bus.endpoint, bus.run_key, bus.keys, sampling=sampling)
            startup_s = world.connect(robots)
            bar = _Progress(steps, progress, f"{world.n} robot processes connected in {startup_s:.1f} s")
            done, outcome = 0, "completed"
            try:
                while done < steps:
                    bar.update(done + 1, world.step(done))
                    done += 1
                    if not world.running(done):
                        outcome = f"no robot left: every robot failed by step {done - 1}"
                        break
            finally:
                bar.close()
            wall_s = time.perf_counter() - world.t0
            codes = world.stop(done)
            log.close()
        except BaseException:
            if log is not None:
                log.abandon()
            raise
        finally:
            if robots is not None:
                robots.close()
            bus.close()
        spec = runtime.spec
        summary = {
            "scenario": str(scenario), "name": sc.name, "seed": seed, "robots_n": world.n, "steps": steps,
            "steps_run": done, "outcome": outcome,
            "mode": "lockstep" if rate_hz is None else "real time", "rate_hz": rate_hz,
            "deadlines": None if rate_hz is None else {"beacon": BEACON_BY, "token": TOKEN_BY,
                                                       **({"cost": COST_BY} if runtime.joint else {}),
                                                       "command": COMMAND_BY, "period_ms": 1e3 / rate_hz},
            "network": net.as_dict(), "export": str(export),
            "policy": {"rule": runtime.rule, "candidates": runtime.candidates, "frame": runtime.frame,
                       "sampler": spec["sampler"]["name"], "sampling_steps": spec["sampler"]["steps"],
                       "sha256": spec.get("source", {}).get("sha256"), "sampling": runtime.sampling_spec,
                       "noise": "robot"},
            "final_cost": world.cost[-1] if done == steps else None, "cost": world.cost,
            "startup_s": startup_s, "wall_s": wall_s, "steps_per_s": done / wall_s,
            **world.summary(codes),
        }
        write_json_atomic(out / "summary.json", summary)
    if done < steps:
        raise MadpError(f"the swarm ended after {done} of {steps} steps, {outcome} (the run does not score; "
                        f"{out / 'summary.json'} says which robot failed when and why)")
    return summary
