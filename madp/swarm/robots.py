"""The robot processes of a swarm: started by the world (one ``python -m madp.robot run`` per robot, each
told to exit with the world: :func:`madp.io.workers.die_with_parent`), watched, stopped and, when they
do not stop, killed.

Each robot runs with one thread of everything (onnxruntime ``--threads 1``, OpenMP, BLAS, numba):
a robot's one core. Its key (:mod:`madp.robot.seal`) goes to it alone, on its standard input: never on
its command line or in its environment, which other users can list. What a robot prints goes to a log
file in a temporary directory, read back only to say why a robot ended early; the directory is removed
when the swarm closes.

Before any starts, :func:`check_capacity` refuses more robot processes than the machine holds: each
needs about :data:`ROBOT_MB` MB of memory, and one core runs at most :data:`ROBOTS_PER_CORE` of them.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["ROBOTS_PER_CORE", "ROBOT_MB", "RobotProcesses", "available_mb", "check_capacity", "describe_exit", "hand_key"]

#: Memory (MB) one robot process takes (onnxruntime, numba and its maps), measured at about 240 MB.
ROBOT_MB = 250
#: Robot processes one core runs at most (each steps in turn; beyond, a step takes minutes).
ROBOTS_PER_CORE = 16
#: Seconds a robot has to exit after the stop packet before it is killed.
STOP_WAIT_S = 10.0
_ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


def available_mb() -> float | None:
    """Memory (MB) the system can give new processes (``MemAvailable``), None where it does not say."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_capacity(num_robots: int, memory_mb: float | None = None, cores: int | None = None) -> None:
    """A :class:`madp.errors.SettingError` when ``num_robots`` robot processes need more than this
    machine's available memory (``memory_mb``, default :func:`available_mb`) or its ``cores`` (default
    the cores this process may run on) hold."""
    from madp.errors import SettingError

    memory_mb = available_mb() if memory_mb is None else memory_mb
    if cores is None:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    need = num_robots * ROBOT_MB
    if memory_mb is not None and need > memory_mb:
        raise SettingError("scenario", f"{num_robots} robot processes need about {need / 1024:.1f} GB "
                                       f"({ROBOT_MB} MB each) and this machine has {memory_mb / 1024:.1f} GB available: "
                                       f"at most {int(memory_mb // ROBOT_MB)} robots here")
    if num_robots > ROBOTS_PER_CORE * cores:
        raise SettingError("scenario", f"{num_robots} robot processes on {cores} core(s): at most {ROBOTS_PER_CORE} "
                                       f"per core ({ROBOTS_PER_CORE * cores} here), or a control step takes minutes")


def describe_exit(code: int | None) -> str:
    """``running``, ``exit status S`` or ``killed by SIGNAME``, from a Popen return code."""
    if code is None:
        return "running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


def hand_key(proc: subprocess.Popen, key: bytes) -> None:
    """Write ``key`` as one line of hex to ``proc``'s standard input and close it (a robot that has
    already ended reads nothing: its exit says why)."""
    try:
        proc.stdin.write(key.hex().encode() + b"\n")
        proc.stdin.close()
    except (BrokenPipeError, OSError):
        pass


class RobotProcesses:
    """``num_robots`` robot processes of the export in ``export_dir``, connecting to ``endpoint`` under
    ``run_key``, robot i handed ``keys[i]`` on its standard input. Must be created on the thread that
    lives as long as the world (the kernel's parent-death signal follows the thread that started a child)."""

    def __init__(self, num_robots: int, export_dir: str | Path, endpoint: str, run_key: str, keys: list[bytes],
                 threads: int = 1, sampling: str | None = None):
        self.logs = Path(tempfile.mkdtemp(prefix="madp-swarm-"))
        env = {**os.environ, **_ONE_THREAD}
        self.procs: list[subprocess.Popen] = []
        try:
            for i in range(num_robots):
                cmd = [sys.executable, "-m", "madp.robot", "run", "--export", str(export_dir), "--id", str(i),
                       "--endpoint", endpoint, "--key", run_key, "--secret", "-", "--threads", str(threads),
                       "--parent", str(os.getpid())]
                cmd += ["--sampling", sampling] if sampling else []
                with open(self.logs / f"robot_{i}.log", "wb") as log:
                    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=log, stderr=subprocess.STDOUT, env=env)
                self.procs.append(proc)
                hand_key(proc, keys[i])
        except BaseException:
            self.close()
            raise

    @property
    def pids(self) -> list[int]:
        return [p.pid for p in self.procs]

    def exited(self, robot: int) -> int | None:
        """Robot ``robot``'s return code (negative: the signal that ended it), or None while it runs."""
        return self.procs[robot].poll()

    def last_words(self, robot: int) -> str:
        """The last line robot ``robot`` printed (empty when none); after a traceback, the exception's line
        with it."""
        try:
            lines = [x.strip() for x in (self.logs / f"robot_{robot}.log").read_text(errors="replace").splitlines() if x.strip()]
        except OSError:
            return ""
        if len(lines) > 1 and "internal error" in lines[-1]:
            return f"{lines[-2]} ({lines[-1]})"
        return lines[-1] if lines else ""

    def wait_all(self, timeout_s: float = STOP_WAIT_S) -> list[int | None]:
        """Wait up to ``timeout_s`` for every robot to exit; kill the rest; return every return code."""
        end = time.monotonic() + timeout_s
        for p in self.procs:
            try:
                p.wait(timeout=max(end - time.monotonic(), 0.0))
            except subprocess.TimeoutExpired:
                pass
        codes = [p.poll() for p in self.procs]
        self.kill()
        return codes

    def kill(self) -> None:
        """SIGKILL every robot still running, and reap them all."""
        for p in self.procs:
            if p.poll() is None:
                try:
                    p.kill()
                except ProcessLookupError:
                    pass
        for p in self.procs:
            try:
                p.wait(timeout=STOP_WAIT_S)
            except subprocess.TimeoutExpired:  # pragma: no cover (SIGKILL of a child cannot be refused)
                pass

    def close(self) -> None:
        """Kill what still runs and remove the logs."""
        self.kill()
        shutil.rmtree(self.logs, ignore_errors=True)
