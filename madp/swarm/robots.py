"""The robot processes of a swarm: started by the world (one ``python -m madp.robot run`` per robot, each
told to exit with the world: :func:`madp.io.workers.die_with_parent`), watched, stopped and, when they
do not stop, killed.

Each robot runs with one thread of everything (onnxruntime ``--threads 1``, OpenMP, BLAS, numba):
a robot's one core. What a robot prints goes to a log file in a temporary directory, read back only
to say why a robot ended early; the directory is removed when the swarm closes.
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

__all__ = ["RobotProcesses", "describe_exit"]

#: Seconds a robot has to exit after the stop packet before it is killed.
STOP_WAIT_S = 10.0
_ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


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


class RobotProcesses:
    """``num_robots`` robot processes of the export in ``export_dir``, connecting to ``endpoint`` under
    ``run_key``. Must be created on the thread that lives as long as the world (the kernel's
    parent-death signal follows the thread that started a child)."""

    def __init__(self, num_robots: int, export_dir: str | Path, endpoint: str, run_key: str, threads: int = 1,
                 sampling: str | None = None):
        self.logs = Path(tempfile.mkdtemp(prefix="madp-swarm-"))
        env = {**os.environ, **_ONE_THREAD}
        self.procs: list[subprocess.Popen] = []
        try:
            for i in range(num_robots):
                cmd = [sys.executable, "-m", "madp.robot", "run", "--export", str(export_dir), "--id", str(i),
                       "--endpoint", endpoint, "--key", run_key, "--threads", str(threads), "--parent", str(os.getpid())]
                cmd += ["--sampling", sampling] if sampling else []
                with open(self.logs / f"robot_{i}.log", "wb") as log:
                    self.procs.append(subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                                       env=env))
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
