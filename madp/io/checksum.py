"""The checksum of a file: the one SHA-256 madp records for shards, policy files, exported graphs and
imported logs, and checks where it reads them back (torch-free: the robot runtime checks its graphs)."""

from __future__ import annotations

import hashlib
import os
from typing import Union

from madp.errors import InputError

PathLike = Union[str, "os.PathLike[str]"]


def sha256_file(path: PathLike, chunk_bytes: int = 8 << 20) -> str:
    """Hex SHA-256 of a file's bytes, read in ``chunk_bytes`` pieces; a one-line :class:`InputError`
    naming the file when it cannot be read."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            while True:
                block = f.read(chunk_bytes)
                if not block:
                    break
                h.update(block)
    except OSError as e:
        raise InputError(f"{path}: cannot read file ({e.strerror or e})") from None
    return h.hexdigest()


__all__ = ["sha256_file"]
