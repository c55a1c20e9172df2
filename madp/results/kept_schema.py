"""The schema of a results folder's ``kept.json`` (:mod:`madp.results.pages` reads it): every field's
type, checked before a field is used, so a wrong one is a one-line :class:`madp.errors.InputError`
naming the file and the field (``default.dirs``, ``options[2].label``, ``runs.NAME.commit``), never a
TypeError deep in the report.

A schema is a type (``str``), a list ``[item]`` (non-empty), a ``dict`` of fields ``{name: schema}``
(the names in :data:`OPTIONAL` may be absent; other fields are allowed) or ``{str: schema}``, a map
from any name to values of one schema.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from madp.errors import InputError

__all__ = ["KEPT_SCHEMA", "OPTIONAL", "check_kept"]

#: ``kept.json``: the default's directories, the options measured against it, the runs' dates and commits
#: and, optionally, a kept ``madp bench infer --out`` file of the default's control step.
KEPT_SCHEMA: dict = {
    "about": str,
    "default": {"label": str, "dirs": [str]},
    "options": [{"name": str, "label": str, "dirs": [str], "report": str}],
    "runs": {str: {"date": str, "commit": str}},
    "bench": {"file": str, "date": str, "commit": str, "machine": str, "command": str},  # madp.results.notes
}
#: Fields that may be absent (by their dotted path with ``[]`` for list items).
OPTIONAL = frozenset({"about", "default.label", "options", "options[].report", "runs", "bench"})

_NAMES = {str: "a string", list: "a non-empty list", dict: "an object"}


def _describe(value: Any) -> str:
    text = repr(value)
    return f"{type(value).__name__} {text[:40]}{'...' if len(text) > 40 else ''}"


def _check(value: Any, schema: Any, where: str, generic: str, path: Path) -> None:
    def fail(expected: str) -> None:
        raise InputError(f"{path}: {where or 'the file'}: expected {expected}, got {_describe(value)}")

    if isinstance(schema, type):
        if not isinstance(value, schema) or (schema is str and not value):
            fail(_NAMES.get(schema, schema.__name__))
    elif isinstance(schema, list):
        if not isinstance(value, list) or not value:
            fail("a non-empty list")
        for k, item in enumerate(value):
            _check(item, schema[0], f"{where}[{k}]", f"{generic}[]", path)
    elif str in schema:  # a map: any name to one schema
        if not isinstance(value, dict):
            fail("an object")
        for name, item in value.items():
            _check(item, schema[str], f"{where}.{name}", f"{generic}.*", path)
    else:
        if not isinstance(value, dict):
            fail("an object")
        for name, sub in schema.items():
            w, g = f"{where}.{name}" if where else name, f"{generic}.{name}" if generic else name
            if name not in value:
                if g not in OPTIONAL:
                    raise InputError(f"{path}: {w}: missing (expected {_kind(sub)})")
                continue
            _check(value[name], sub, w, g, path)


def _kind(schema: Any) -> str:
    if isinstance(schema, type):
        return _NAMES.get(schema, schema.__name__)
    return "a non-empty list" if isinstance(schema, list) else "an object"


def check_kept(spec: Any, path: str | Path) -> dict:
    """``spec`` (``kept.json`` read from ``path``) when it fits :data:`KEPT_SCHEMA`; else an
    :class:`madp.errors.InputError` naming ``path`` and the first field that does not."""
    _check(spec, KEPT_SCHEMA, "", "", Path(path))
    return spec
