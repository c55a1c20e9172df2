"""``--overwrite`` removes only what madp wrote.

A command that may replace an output directory lists the files it (or an earlier madp job) wrote
there — the shards a manifest or shard record names, a suite's job files and the report's file
list. :func:`clear_owned` checks every file of the directory against that list first: anything
else (a user's notes, another tool's output) makes it refuse, naming the file, before a single
file is removed. madp's temporary files and lock are always its own.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

from madp.errors import MadpError

from .atomic import is_temp
from .lock import LOCK_FILENAME


class NotOwned(MadpError):
    """``--overwrite`` met a file madp did not write (one-line message naming it)."""


def foreign_files(root: str | os.PathLike, owned: Iterable[str | os.PathLike]) -> list[Path]:
    """Files (and links) under ``root`` that are neither in ``owned`` (relative paths) nor madp's
    temporary files or lock, sorted."""
    root = Path(root)
    mine = {Path(p) for p in owned}
    out = []
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        d = Path(dirpath)
        links = [n for n in dirnames if (d / n).is_symlink()]  # a linked directory is a foreign entry
        for name in sorted(filenames + links):
            rel = (d / name).relative_to(root)
            if rel in mine or is_temp(rel) or rel == Path(LOCK_FILENAME):
                continue
            out.append(d / name)
    return sorted(out)


def clear_owned(root: str | os.PathLike, owned: Iterable[str | os.PathLike], flag: str = "--out") -> int:
    """Remove the files madp wrote under ``root``, then the directories that became empty.

    Raises :class:`NotOwned` (nothing removed) if any other file is there. Returns the number of
    files removed. The lock file stays (its holder removes it).
    """
    root = Path(root)
    owned = [Path(p) for p in owned if not Path(p).is_absolute() and ".." not in Path(p).parts]
    foreign = foreign_files(root, owned)
    if foreign:
        more = f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
        raise NotOwned(f"{foreign[0]}: not written by madp{more}; --overwrite removes only madp's own files — "
                       f"move it away or choose another {flag}")
    n = 0
    for p in [*(root / q for q in owned), *(p for p in root.rglob("*") if is_temp(p))]:
        if p.is_file() or p.is_symlink():
            p.unlink()
            n += 1
    for dirpath, _, _ in sorted(os.walk(root), key=lambda t: -len(t[0])):
        if Path(dirpath) != root:
            try:
                os.rmdir(dirpath)
            except OSError:
                pass
    return n
