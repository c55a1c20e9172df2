"""Who may speak for a robot: the per-run keys of a swarm and the tag that binds every record to its
sender and its key (``madp swarm``, :mod:`madp.robot.process`). Standard library only.

The world draws a fresh secret for each run (:func:`new_secret`); robot i's key is
``HMAC-SHA256(secret, "madp-robot" | i)`` (:func:`robot_key`), handed to robot i alone over its own
channel: its standard input, or a file only its user can read (:func:`read_key`). Never on a command
line or in the environment, which other users of the machine can list.

Every record on a robot's keys carries a 16-byte tag after it (:func:`seal`): the HMAC-SHA256 of the
key expression it travels on (``madp/RUN/robot/I/in|out/NAME``: the run, the robot, the direction and
the kind) and the record (which holds the step), under robot i's key. :func:`unseal` returns the
record only when the tag is right, so a record from anyone without robot i's key, one moved to another
robot's keys or another run's, or one sent back the other way is dropped, never read. The
transport's password of robot i (:func:`transport_password`) is derived from the same key, so one
secret is all a robot is handed.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import stat
import sys
from pathlib import Path

from madp.errors import InputError

__all__ = ["KEY_BYTES", "TAG_BYTES", "new_secret", "read_key", "robot_key", "seal", "transport_password",
           "transport_user", "unseal"]

#: Bytes of a run's secret and of a robot's key; bytes of a record's tag.
KEY_BYTES, TAG_BYTES = 32, 16


def new_secret() -> bytes:
    """A fresh run secret (:data:`KEY_BYTES` random bytes)."""
    return secrets.token_bytes(KEY_BYTES)


def robot_key(secret: bytes, robot: int) -> bytes:
    """Robot ``robot``'s key of the run of ``secret``."""
    return hmac.new(secret, b"madp-robot|%d" % int(robot), hashlib.sha256).digest()


def transport_user(robot: int) -> str:
    """Robot ``robot``'s user name on the world's Zenoh endpoint."""
    return f"robot{int(robot)}"


def transport_password(key: bytes) -> str:
    """The password a robot of ``key`` gives the world's Zenoh endpoint (hex)."""
    return hmac.new(key, b"madp-transport", hashlib.sha256).hexdigest()


def _tag(key: bytes, key_expr: str, record: bytes) -> bytes:
    mac = hmac.new(key, key_expr.encode() + b"\x00", hashlib.sha256)
    mac.update(record)
    return mac.digest()[:TAG_BYTES]


def seal(key: bytes, key_expr: str, record: bytes) -> bytes:
    """``record`` with its tag under ``key`` for ``key_expr`` (the key expression it is put on)."""
    record = bytes(record)
    return record + _tag(key, key_expr, record)


def unseal(key: bytes, key_expr: str, data: bytes) -> bytes | None:
    """The record of ``data`` when its tag is robot ``key``'s for ``key_expr``; None otherwise."""
    data = bytes(data)
    if len(data) <= TAG_BYTES:
        return None
    record, tag = data[:-TAG_BYTES], data[-TAG_BYTES:]
    return record if hmac.compare_digest(tag, _tag(key, key_expr, record)) else None


def read_key(source: str) -> bytes:
    """A robot's key from ``source``: ``-`` (one line of hex on standard input) or a file of one line
    of hex that only its owner may read or write (mode 0600 or stricter); an
    :class:`madp.errors.InputError` naming it otherwise."""
    if source == "-":
        text, where = sys.stdin.readline(), "standard input"
    else:
        path = Path(source)
        try:
            mode = path.stat().st_mode
            if mode & (stat.S_IRWXG | stat.S_IRWXO):
                raise InputError(f"{path}: a robot's key file must be readable by its owner alone (chmod 600 {path})")
            text, where = path.read_text(), str(path)
        except OSError as e:
            raise InputError(f"{path}: cannot read the robot's key ({e.strerror or type(e).__name__})") from None
    try:
        key = bytes.fromhex(text.strip())
    except ValueError:
        key = b""
    if len(key) != KEY_BYTES:
        raise InputError(f"{where}: expected the robot's key as {2 * KEY_BYTES} hex digits")
    return key
