"""One madp job per output directory: an advisory lock, ``DIR/.madp.lock``.

The job holds ``fcntl.flock(LOCK_EX)`` on the file for as long as it writes the directory, and
writes its pid into it, so a second job stops at once with one line naming that pid. The kernel
drops the lock when the holder dies, however it dies (``kill -9`` included): a stale file never
blocks a rerun, and its pid only says who had it last. A job that ends normally removes the file
(and the directory, if the job created it and left it empty).

Child processes that inherited the descriptor (forked DataLoader workers) keep the lock until
they exit. So when the pid in the file no longer runs, the lock is held by such orphans, which
end with their parent: the job waits up to :data:`ORPHAN_WAIT_S` for them before giving up.
"""

from __future__ import annotations

import fcntl
import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Optional

from madp.errors import MadpError

#: Name of the lock file inside a locked directory. Never part of a dataset, run or suite.
LOCK_FILENAME = ".madp.lock"
#: How long a job waits for the orphaned children of a dead holder to exit.
ORPHAN_WAIT_S = 15.0


class DirectoryLocked(MadpError):
    """Another madp job is writing the directory (a one-line message naming its pid)."""


def pid_running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie (on Linux)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True  # no /proc: trust kill(0)
    return stat.rsplit(")", 1)[-1].split()[0] != "Z"


def _read_pid(fd: int) -> Optional[int]:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
        return int(text) if text else None
    except (OSError, ValueError):
        return None


def _acquire(lock: Path, flag: str) -> int:
    """Open and flock ``lock``; return the descriptor, or raise :class:`DirectoryLocked`."""
    deadline = None
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = _read_pid(fd)
            os.close(fd)
            if pid is None or pid_running(pid):
                holder = f"pid {pid}" if pid is not None else "a process that is starting"
                raise DirectoryLocked(f"{lock.parent}: in use by another madp job ({holder}); "
                                      f"wait for it to end or choose another {flag}") from None
            deadline = deadline or time.monotonic() + ORPHAN_WAIT_S
            if time.monotonic() > deadline:
                raise DirectoryLocked(f"{lock.parent}: still locked by the child processes of pid {pid}, which "
                                      f"has ended; stop them or choose another {flag}") from None
            time.sleep(0.1)
            continue
        # The previous holder may have removed the file between our open() and flock(): then we
        # hold a lock on a file nobody else will ever open; start again.
        try:
            current = os.stat(lock).st_ino
        except FileNotFoundError:
            current = None
        if current != os.fstat(fd).st_ino:
            os.close(fd)
            continue
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        return fd


@contextmanager
def locked_dir(path: str | os.PathLike, flag: str = "--out") -> Iterator[Path]:
    """Hold the lock of directory ``path`` (created if missing) for the ``with`` block.

    ``flag`` is the option that chose the directory, named in the refusal. Raises
    :class:`DirectoryLocked` when another job holds it.
    """
    path = Path(path)
    created = not path.exists()
    path.mkdir(parents=True, exist_ok=True)
    lock = path / LOCK_FILENAME
    fd = _acquire(lock, flag)
    try:
        yield path
    finally:
        try:
            lock.unlink()  # while still holding it: a waiter then sees a new file and retries
        except FileNotFoundError:
            pass
        os.close(fd)
        if created:
            try:
                path.rmdir()  # only if empty: a job that failed at once leaves no trace
            except OSError:
                pass
