"""Reading a JSON file a person or an earlier job wrote: its value, or a one-line
:class:`~madp.errors.InputError` that names the file."""

from __future__ import annotations

import json
import os
from pathlib import Path

from madp.errors import InputError


def read_json(path: str | os.PathLike, missing: str) -> object:
    """The value of the JSON file ``path``. A missing file raises ``InputError("PATH: not found; " +
    missing)`` (``missing`` says what was expected, or how to make it); an unreadable or malformed one
    ``InputError("PATH: unreadable (ERROR)")``."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: not found; {missing}") from None
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: unreadable ({type(e).__name__}: {e})") from None
