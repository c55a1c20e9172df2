"""What a robot accepts from its inbox: every received :class:`madp.sim.network.Message` is checked
before anything of it reaches the networks, and a bad one is dropped and counted, never raised.

A message is dropped, under the first reason that applies (:class:`InboxCounts`), when:

* ``malformed``: it is not a :class:`Message`, its sender or step is not a whole number, or its
  position is not 2 numbers;
* ``non_finite``: its position or token holds NaN or ±inf;
* ``bad_token``: it carries no token, or one whose size is not the model's token size;
* ``future``: it was sent at a later control step than the robot's own;
* ``stale``: it was sent more than ``max_age`` steps ago (tokens are computed in the frame of their
  own step: the runtime uses this step's by default);
* ``duplicate``: its sender is the robot itself, or another message of the inbox passed the checks
  above with the same sender (all of that sender's messages are dropped: which one is genuine
  cannot be told).

A message that passes is ``out_of_range`` when the sender's position is not within r_c of the
robot's (it is then not part of the robot's neighbourhood: ignored, not an error), else ``accepted``.
"""

from __future__ import annotations

import numbers
from collections import Counter
from dataclasses import asdict, dataclass

import numpy as np

from madp.sim.network import Message

__all__ = ["DROP_REASONS", "InboxCounts", "read_inbox"]

#: Why a message is dropped, in the order the checks apply.
DROP_REASONS = ("malformed", "non_finite", "bad_token", "future", "stale", "duplicate")


@dataclass
class InboxCounts:
    """Counts of one inbox: ``received`` messages, of which ``accepted`` (in the neighbourhood),
    ``out_of_range`` and the dropped ones by reason (module docstring)."""

    received: int = 0
    accepted: int = 0
    out_of_range: int = 0
    malformed: int = 0
    non_finite: int = 0
    bad_token: int = 0
    future: int = 0
    stale: int = 0
    duplicate: int = 0

    @property
    def dropped(self) -> int:
        return sum(getattr(self, r) for r in DROP_REASONS)

    def as_dict(self) -> dict[str, int]:
        return {**asdict(self), "dropped": self.dropped}


def _whole(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _check(msg, robot_id: int, step: int, token_dim: int, max_age: int | None) -> tuple[str | None, tuple | None]:
    """``(reason, None)`` for a bad message, else ``(None, (sender, position_m [2] float64, token [D] float32))``."""
    if not isinstance(msg, Message) or not _whole(msg.sender) or not _whole(msg.step):
        return "malformed", None
    try:
        pos = np.asarray(msg.position_m, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return "malformed", None
    if pos.shape != (2,):
        return "malformed", None
    if not np.isfinite(pos).all():
        return "non_finite", None
    if msg.token is None:
        return "bad_token", None
    try:
        token = np.asarray(msg.token)
        if token.dtype.kind not in "fiu" or token.shape != (token_dim,):
            return "bad_token", None
        token = token.astype(np.float32)
    except (TypeError, ValueError, OverflowError):
        return "bad_token", None
    with np.errstate(over="ignore"):
        if not np.isfinite(token).all():
            return "non_finite", None
    if int(msg.step) > step:
        return "future", None
    if max_age is not None and int(msg.step) < step - max_age:
        return "stale", None
    if int(msg.sender) == robot_id:
        return "duplicate", None
    return None, (int(msg.sender), pos, token)


def read_inbox(inbox, robot_id: int, step: int, position_m: np.ndarray, token_dim: int, radius_m: float,
               within=None, max_age: int | None = 0) -> tuple[list[tuple[int, np.ndarray, np.ndarray]], InboxCounts]:
    """The messages of ``inbox`` (any iterable; None is an empty inbox) robot ``robot_id`` keeps at
    control step ``step``: ``([(sender, position_m [2], token [token_dim]), ...] ascending by sender,
    counts)``. ``within(position_m [M, 2]) -> [M] bool`` decides who is in range (default: Euclidean
    distance < ``radius_m`` in float64). Never raises on a message's content."""
    counts = InboxCounts()
    good: list[tuple[int, np.ndarray, np.ndarray]] = []
    for msg in list(inbox or ()):
        counts.received += 1
        try:
            reason, item = _check(msg, robot_id, step, token_dim, max_age)
        except Exception:  # anything else a hostile object does: one more bad message
            reason, item = "malformed", None
        if reason is not None:
            setattr(counts, reason, getattr(counts, reason) + 1)
        else:
            good.append(item)
    senders = Counter(s for s, _, _ in good)
    dup = {s for s, c in senders.items() if c > 1}
    counts.duplicate += sum(senders[s] for s in dup)
    good = sorted((g for g in good if g[0] not in dup), key=lambda g: g[0])
    if good:
        pos = np.stack([g[1] for g in good])
        if within is None:
            inside = ((pos - np.asarray(position_m, dtype=np.float64)) ** 2).sum(1) < radius_m * radius_m
        else:
            inside = np.asarray(within(pos), dtype=bool)
        counts.out_of_range = int((~inside).sum())
        good = [g for g, keep in zip(good, inside) if keep]
    counts.accepted = len(good)
    return good, counts
