"""The network between the robots: what each robot has received, over links that lose and delay messages.

Every robot holds only what it knows: its own sensed map, its own position estimate, and an inbox of
the messages it has received. A :class:`Message` carries the sender's id, the step at which it was
sent, the position the sender reported (its own estimate) and, for MADP, its token; LPAC-K3's graph
rounds send :class:`HopMessage`\\ s (one round of messages per hop of every graph layer).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Message:
    """One robot's broadcast at one control step.

    ``sender``: the robot's id; ``step``: the control step at which it was sent; ``position_m`` [2]:
    the position the sender reported (its own estimate, metres); ``token`` [token_dim] float32 or
    None: MADP's token ``[z, p]`` (the perception CNN's output and the neighbourhood offset)."""

    sender: int
    step: int
    position_m: np.ndarray
    token: np.ndarray | None = None


@dataclass(frozen=True)
class HopMessage:
    """One round of LPAC-K3's graph messages: the sender's features ``features`` [F] float32 of round
    ``round`` (layer l, hop k: round l·K + k − 1) at control step ``step``."""

    sender: int
    step: int
    round: int
    features: np.ndarray


__all__ = ["HopMessage", "Message"]
