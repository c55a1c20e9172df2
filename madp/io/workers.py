"""Worker processes that end when their parent dies.

A pool worker whose parent is killed (``kill -9``, the OOM killer) would otherwise finish its task
and write files that a rerun is writing too. :func:`die_with_parent` is the pools' initializer: on
Linux it asks the kernel for SIGKILL when the parent exits (``prctl(PR_SET_PDEATHSIG)``); elsewhere,
or if that fails, a daemon thread watches the parent pid. Either way it first checks that the
parent did not die before the worker got this far.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1
#: Seconds between checks of the fallback watcher.
WATCH_INTERVAL_S = 0.5


def _prctl_pdeathsig() -> bool:
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch(parent_pid: int) -> None:
    while True:
        if os.getppid() != parent_pid:
            os._exit(1)
        time.sleep(WATCH_INTERVAL_S)


def die_with_parent(parent_pid: int) -> None:
    """Make this process exit as soon as ``parent_pid`` (its parent) does."""
    armed = _prctl_pdeathsig()
    if os.getppid() != parent_pid:  # the parent died before the kernel was told
        os._exit(1)
    if not armed:
        threading.Thread(target=_watch, args=(parent_pid,), daemon=True, name="madp-parent-watch").start()
