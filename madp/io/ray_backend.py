"""Ray: the embarrassingly parallel jobs (datagen shard tasks, evaluation jobs) on a Ray cluster.

:func:`ray_imap_unordered` is the Ray counterpart of ``multiprocessing.Pool.imap_unordered``: the
same module-level worker function the local pool calls runs as one Ray task per item, and the
results come back to the driver as tasks finish (the driver advances its progress bar with them).
Everything else — the directory lock, the plan, resume, temporary names and renames, records and
manifests — stays with the caller, so a Ray run writes exactly the bytes of a local one into the
output directory, which must therefore be a path every node of the cluster sees.

A task whose worker process dies (killed, out of memory, a lost node) is run again by Ray, up to
:data:`MAX_RETRIES` times; a task is a pure function of its arguments and writes under a temporary
name it renames only when complete, so the retry writes the same bytes and the dead attempt leaves
at most a temporary file, which the caller removes while it holds the directory's lock. An
exception raised by a task is not retried: it reaches the driver as the task's own exception.

``address``: ``None`` or ``"local"`` starts a Ray instance on this machine for the run (and stops
it afterwards); ``"auto"`` joins the cluster running here (``ray start --head`` / ``--address``);
anything else is passed to ``ray.init(address=...)`` (``HOST:PORT``, ``ray://HOST:10001``). When
this process is already connected (``ray.init`` called before), that connection is used as it is.
Ray is the optional extra ``madp[ray]``.
"""

from __future__ import annotations

import functools
import logging
from contextlib import contextmanager
from typing import Any, Callable, Iterable, Iterator, Optional

from madp.errors import SettingError

#: ``--ray`` given without an address: start a Ray instance on this machine for the run.
RAY_LOCAL = "local"
#: How many times Ray re-runs a task whose worker died.
MAX_RETRIES = 3
#: One BLAS/OpenMP thread per task, as in the local worker processes.
THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


class RayUnavailable(SettingError):
    """Ray asked for (setting ``ray``, ``--ray``) but not installed (a one-line message saying what to install)."""


def import_ray():
    """The ``ray`` module, or :class:`RayUnavailable`."""
    try:
        import ray
    except ImportError:
        raise RayUnavailable("ray", 'Ray is not installed; pip install "madp[ray]"') from None
    return ray


@contextmanager
def ray_session(address: Optional[str] = None) -> Iterator[Any]:
    """Connect to Ray for the ``with`` block (see the module docstring for ``address``); yields ``ray``.

    Disconnects afterwards (stopping a Ray it started) unless the process was connected before."""
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    if address in (None, "", RAY_LOCAL):
        # Ray nices its workers (15) by default; tasks here run at this process's priority, as the
        # local worker processes do (on a busy machine a niced task loses its core to other work)
        ray.init(include_dashboard=False, logging_level=logging.WARNING, _system_config={"worker_niceness": 0})
    else:
        ray.init(address=address, logging_level=logging.WARNING)
    try:
        yield ray
    finally:
        ray.shutdown()


def _call(fn: Callable[[Any], Any], item: Any) -> Any:
    return fn(item)


@functools.cache
def _remote(ray) -> Any:
    """:func:`_call` as a Ray task (made once: Ray exports it once per connection)."""
    return ray.remote(_call).options(num_cpus=1, max_retries=MAX_RETRIES, runtime_env={"env_vars": THREAD_ENV})


def ray_imap_unordered(fn: Callable[[Any], Any], items: Iterable[Any], address: Optional[str] = None) -> Iterator[Any]:
    """``fn(item)`` for every item, one Ray task each (one CPU, :data:`MAX_RETRIES` retries after a
    worker's death), yielded in the order the tasks finish. ``fn`` must be importable (a module-level
    function: Ray ships it by reference). A task's exception is raised here as itself."""
    with ray_session(address) as ray:
        pending = [_remote(ray).remote(fn, item) for item in items]
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                try:
                    yield ray.get(done[0])
                except ray.exceptions.RayTaskError as e:
                    if isinstance(e.cause, Exception):
                        raise e.cause from e
                    raise
        finally:
            for ref in pending:  # the driver stops early (an error, Ctrl-C): drop the rest
                ray.cancel(ref, force=True)
