"""Atomic file replacement with temporary names unique per writer.

A file is written under ``NAME.<pid>.tmp`` beside its destination, flushed to disk and renamed
over it, so a reader sees the old file or the whole new one, and two processes (a job and the
orphaned worker of a killed one) never write the same temporary file. Leftovers of killed writers
match :data:`TMP_GLOB`; a job removes them while it holds the directory's lock.
"""

from __future__ import annotations

import json
import os
import re
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

#: Matches (as a glob) every temporary file this module names; :func:`is_temp` is the exact test.
TMP_GLOB = "*.tmp*"
_TEMP_NAME = re.compile(r"^.+\.\d+\.tmp(\.[A-Za-z0-9]+)?$")


def temp_path(path: str | os.PathLike, ext: str = "") -> Path:
    """``path``'s temporary sibling for this process: ``NAME.<pid>.tmp`` (plus ``ext``, e.g. ``.npz``
    for writers that insist on a suffix)."""
    path = Path(path)
    return path.with_name(f"{path.name}.{os.getpid()}.tmp{ext}")


def is_temp(path: str | os.PathLike) -> bool:
    """Whether ``path`` is named like a temporary file of :func:`temp_path`."""
    return _TEMP_NAME.match(Path(path).name) is not None


def named(err: OSError, path: str | os.PathLike) -> OSError:
    """``err`` with ``path`` as its file name when it has none (a failed write of an open file, e.g.
    a full disk), so its one-line message says which file could not be written."""
    if err.filename is None and err.errno is not None:
        return OSError(err.errno, err.strerror or str(err), os.fspath(path))
    return err


@contextmanager
def atomic_path(path: str | os.PathLike, ext: str = "", fsync: bool = True) -> Iterator[Path]:
    """Yield ``path``'s temporary sibling (:func:`temp_path`) for the caller to write; when the block
    ends normally, fsync it (unless ``fsync`` is False) and rename it over ``path``. On any error the
    temporary file is removed and an OSError names ``path`` (:func:`named`).

        with atomic_path(out, ".mp4") as tmp:
            writer_that_insists_on_a_suffix(tmp)
    """
    path = Path(path)
    tmp = temp_path(path, ext)
    try:
        yield tmp
        if fsync:
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        os.replace(tmp, path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise named(e, path) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | os.PathLike, text: str, fsync: bool = True) -> Path:
    """Write ``text`` to ``path`` atomically (temporary sibling, fsync, rename); create parents."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, fsync=False) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
        f.flush()
        if fsync:
            os.fsync(f.fileno())
    return path


def write_json_atomic(path: str | os.PathLike, obj: object) -> Path:
    """``obj`` as JSON (indent 1, trailing newline) at ``path``, atomically (:func:`write_text_atomic`)."""
    return write_text_atomic(path, json.dumps(obj, indent=1) + "\n")


def remove_temps(root: str | os.PathLike) -> int:
    """Remove every temporary file under ``root`` (call only while holding its lock). Returns the count."""
    n = 0
    for p in Path(root).rglob(TMP_GLOB):
        if is_temp(p) and p.is_file():
            p.unlink(missing_ok=True)
            n += 1
    return n
