"""Reading the ``.npz`` files the training commands write (arrays plus a JSON ``meta`` with a format
version), with one-line errors for a missing, foreign, outdated or non-finite file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from madp.errors import InputError

__all__ = ["load_npz"]


def load_npz(path: Path, keys, what: str, command: str, fmt: int, finite=()) -> tuple[dict, dict]:
    """``({key: array}, meta)`` of the ``.npz`` at ``path``: the arrays ``keys`` and the JSON ``meta``,
    which must hold ``format`` ``fmt``; the arrays ``finite`` must hold no NaN or infinity. ``what`` names
    the file in errors (``a critic labels file``), ``command`` the one that makes it."""
    path = Path(path)
    try:
        with np.load(path) as z:
            data = {k: z[k] for k in keys}
            meta = json.loads(str(z["meta"]))
    except FileNotFoundError:
        raise InputError(f"{path}: not found; make it with {command}") from None
    except Exception as e:  # a truncated or foreign file: zipfile's, numpy's or json's errors
        raise InputError(f"{path}: not {what} ({type(e).__name__})") from None
    if meta.get("format") != fmt:
        raise InputError(f"{path}: format {meta.get('format')!r}, expected {fmt}")
    if not all(np.isfinite(data[k]).all() for k in finite):
        raise InputError(f"{path}: the arrays hold NaN or infinity")
    return data, meta
