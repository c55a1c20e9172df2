"""What a robot accepts from its inbox: every received :class:`madp.sim.network.Message` is checked
before anything of it reaches the networks, and a bad one is dropped and counted, never raised.

A message is dropped, under the first reason that applies (:class:`InboxCounts`), when:

* ``malformed``: it is not a :class:`Message`, its sender is not a whole number in
  ``[0, MAX_SENDER]``, its step not a whole number in ``[0, MAX_STEP]``, or its position is not 2 numbers;
* ``non_finite``: its position or token holds NaN or ±inf;
* ``bad_token``: it carries no token, or one whose size is not the model's token size;
* ``future``: it was sent at a later control step than the robot's own;
* ``stale``: it was sent more than ``max_age`` steps ago;
* ``other_frame``: it was sent at a step whose frame differs from this step's (``same_frame(step)``
  is False: a token is computed in the frame of the step it was sent, :mod:`madp.robot.frame`, and
  means nothing in another one);
* ``duplicate``: its sender is the robot itself; or another message of the inbox that passed the
  checks above has the same sender and a later step (the newest is kept); or messages of the same
  sender and the same (newest) step differ (all of them are dropped: which one is genuine cannot be
  told; identical copies count as one, the others as duplicates).

A message that passes is ``out_of_range`` when the sender's position is not within r_c of the
robot's (it is then not part of the robot's neighbourhood: ignored, not an error), else ``accepted``.
"""

from __future__ import annotations

import numbers
from dataclasses import asdict, dataclass

import numpy as np

from madp.sim.network import Message
from madp.sim.rules import closer_than_squared

__all__ = ["DROP_REASONS", "InboxCounts", "read_inbox"]

#: Why a message is dropped, in the order the checks apply.
DROP_REASONS = ("malformed", "non_finite", "bad_token", "future", "stale", "other_frame", "duplicate")
#: The largest robot id and control step a message may carry (ids and steps seed the robots' noise).
MAX_SENDER = 2**31 - 1
MAX_STEP = 2**62


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
    other_frame: int = 0
    duplicate: int = 0

    @property
    def dropped(self) -> int:
        return sum(getattr(self, r) for r in DROP_REASONS)

    def as_dict(self) -> dict[str, int]:
        return {**asdict(self), "dropped": self.dropped}


def _whole(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _check(msg, robot_id: int, step: int, token_dim: int | None, max_age: int | None,
           same_frame=None) -> tuple[str | None, tuple | None]:
    """``(reason, None)`` for a bad message, else ``(None, (sender, position_m [2] float64, token [D]
    float32, step))``; with ``token_dim`` None a position beacon (its token, if any, is not read: None)."""
    if not isinstance(msg, Message) or not _whole(msg.sender) or not _whole(msg.step):
        return "malformed", None
    if not (0 <= msg.sender <= MAX_SENDER and 0 <= msg.step <= MAX_STEP):
        return "malformed", None
    try:
        pos = np.asarray(msg.position_m, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return "malformed", None
    if pos.shape != (2,):
        return "malformed", None
    if not np.isfinite(pos).all():
        return "non_finite", None
    token = None
    if token_dim is not None:  # a token message (a beacon's token is not read)
        reason, token = ("bad_token", None) if msg.token is None else _token(msg.token, token_dim)
        if reason is not None:
            return reason, None
    if int(msg.step) > step:
        return "future", None
    if max_age is not None and int(msg.step) < step - max_age:
        return "stale", None
    if same_frame is not None and int(msg.step) != step and not same_frame(int(msg.step)):
        return "other_frame", None
    if int(msg.sender) == robot_id:
        return "duplicate", None
    return None, (int(msg.sender), pos, token, int(msg.step))


def _token(value, token_dim: int) -> tuple[str | None, np.ndarray | None]:
    """A message's token as float32 ``[token_dim]``, or the reason it is dropped."""
    try:
        token = np.asarray(value)
        if token.dtype.kind not in "fiu" or token.shape != (token_dim,):
            return "bad_token", None
        token = token.astype(np.float32)
    except (TypeError, ValueError, OverflowError):
        return "bad_token", None
    with np.errstate(over="ignore"):
        if not np.isfinite(token).all():
            return "non_finite", None
    return None, token


def _newest(good: list[tuple], duplicate: int) -> tuple[list[tuple[int, np.ndarray, np.ndarray]], int]:
    """Per sender, its newest message ``(sender, position_m, token)`` (module docstring's ``duplicate``
    rule), ascending by sender, and the duplicate count grown by what was dropped."""
    by_sender: dict[int, list[tuple]] = {}
    for g in good:
        by_sender.setdefault(g[0], []).append(g)
    kept = []
    for sender in sorted(by_sender):
        msgs = by_sender[sender]
        newest = max(m[3] for m in msgs)
        top = [m for m in msgs if m[3] == newest]
        duplicate += len(msgs) - len(top)
        if all(np.array_equal(m[1], top[0][1]) and np.array_equal(m[2], top[0][2]) for m in top[1:]):
            duplicate += len(top) - 1
            kept.append(top[0][:3])
        else:
            duplicate += len(top)
    return kept, duplicate


def read_inbox(inbox, robot_id: int, step: int, position_m: np.ndarray, token_dim: int | None, radius_m: float,
               within=None, max_age: int | None = 0, same_frame=None
               ) -> tuple[list[tuple[int, np.ndarray, np.ndarray]], InboxCounts]:
    """The messages of ``inbox`` (any iterable; None is an empty inbox) robot ``robot_id`` keeps at
    control step ``step``: ``([(sender, position_m [2], token [token_dim]), ...] ascending by sender,
    counts)``; ``token_dim`` None reads position beacons (their token None). ``within(position_m [M, 2])
    -> [M] bool`` decides who is in range (default: Euclidean
    distance < ``radius_m`` in float64); ``same_frame(sent_step) -> bool`` whether a message of an
    earlier step was computed in this step's frame (None: every frame is this one). Never raises on a
    message's content."""
    counts = InboxCounts()
    good: list[tuple[int, np.ndarray, np.ndarray]] = []
    for msg in list(inbox or ()):
        counts.received += 1
        try:
            reason, item = _check(msg, robot_id, step, token_dim, max_age, same_frame)
        except Exception:  # anything else a hostile object does: one more bad message
            reason, item = "malformed", None
        if reason is not None:
            setattr(counts, reason, getattr(counts, reason) + 1)
        else:
            good.append(item)
    good, counts.duplicate = _newest(good, counts.duplicate)
    if good:
        pos = np.stack([g[1] for g in good])
        if within is None:
            inside = closer_than_squared(pos - np.asarray(position_m, dtype=np.float64), radius_m)
        else:
            inside = np.asarray(within(pos), dtype=bool)
        counts.out_of_range = int((~inside).sum())
        good = [g for g, keep in zip(good, inside) if keep]
    counts.accepted = len(good)
    return good, counts
