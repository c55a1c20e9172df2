"""madp's own exceptions: what the library raises when what it was asked to do cannot be done as asked.

- :class:`MadpError`: the base. Its message is one line that names the value, setting, file or
  directory and says what was expected.
- :class:`SettingError`: a setting (an argument, option or configuration field) has a value madp
  cannot use. ``setting`` is the library's name for it (``num_samples``, ``sampling_steps``); the
  message describes the value and starts with that name. The command line names the flag instead.
- :class:`InputError`: a file or directory madp reads is missing, unreadable or not what it
  expected; the message starts with its path.
- :func:`check_extra`: the ``SettingError`` of a value that needs a module of an extra not installed.

The data layer's :class:`madp.data_schema.DataError`, the simulator's
:class:`madp.sim.ScenarioError`, a locked or foreign output directory
(:class:`madp.io.lock.DirectoryLocked`, :class:`madp.io.owned.NotOwned`) and a missing Ray
(:class:`madp.io.ray_backend.RayUnavailable`) are madp errors too. ``SettingError`` and ``InputError``
are also ``ValueError`` s.

``madp`` (:mod:`madp.cli`) prints a madp error, and an ``OSError`` (a file that cannot be read or
written), as one line ``madp: error: ...`` and exits with status 2; any other exception is a bug in
madp: it prints the traceback and asks for a report, exit status 1.

This module imports nothing of madp, so every layer can raise these.
"""

from __future__ import annotations


class MadpError(Exception):
    """A request madp cannot carry out as asked; the message is one line (newlines are collapsed)."""

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))


class SettingError(MadpError, ValueError):
    """Setting ``setting`` has a value madp cannot use.

    ``SettingError("num_samples", "expected a positive number of samples, got 0")`` reads
    ``num_samples: expected a positive number of samples, got 0``; ``message`` replaces that text
    when it reads better, and then starts with the setting's name too."""

    def __init__(self, setting: str, problem: str = "", message: str | None = None):
        self.setting = setting
        super().__init__(message if message is not None else f"{setting}: {problem}")

    def __reduce__(self):  # rebuilt whole where a worker process raised it
        return type(self), (self.setting, "", str(self))


class InputError(MadpError, ValueError):
    """A file or directory madp reads is missing, unreadable or not what was expected; the message
    starts with its path."""


def check_extra(setting: str, value: str, extra: str, modules: tuple[str, ...]) -> None:
    """A one-line :class:`SettingError`, before any work, when ``value`` of ``setting`` needs a module of
    madp's extra ``extra`` that is not installed (naming the modules and the ``pip install`` that brings them)."""
    import importlib.util

    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    if missing:
        raise SettingError(setting, f"{value} needs {', '.join(missing)}, which is not installed: "
                                    f"pip install 'madp[{extra}]'")
