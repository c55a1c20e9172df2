"""The radio between the robot processes: :mod:`madp.sim.network`'s model (range on the true positions,
loss, delay, kept messages, failures) deciding what each robot hears.

Per control step and phase the world hands the radio what reached it in time: every robot's beacon
(channel ``position``) or token message (channel ``token``); the radio puts them through
:meth:`madp.sim.network.Network.exchange` (the robots that sent nothing this phase marked as not
sending) and returns, for each receiver i, exactly the messages the model delivers to i, each as the
sender's :class:`Message` of the step it was sent. The same channels, payloads and seeds as
``madp rollout`` over the same network (``position``: the reported positions; ``token``: position and
token), so a lockstep swarm hears what the one-process run hears.

The ``cost`` channel (the cost round of the ``_joint`` selection rules) is not drawn by the model: a
robot's cost message of the step goes to every robot that holds its position beacon at that step
(:meth:`Radio.relay`), as the simulator's cost round delivers it wherever it delivered the position.

A message the radio cannot carry (a token or costs of the wrong size, a sender that is not the robot
whose key it came on) is dropped and counted as ``malformed`` for its sender.
"""

from __future__ import annotations

import numpy as np

from madp.sim.network import Message, Network

__all__ = ["CHANNELS", "ChannelCounts", "Radio"]

#: The radio's channels, by phase (beacons, tokens, costs): the first two are the names
#: :mod:`madp.sim.network` draws losses for.
CHANNELS = ("position", "token", "cost")


class ChannelCounts:
    """Per robot counts of one channel, ``[N]`` int64 each: messages it ``sent`` that reached the radio in
    time and their bytes (``sent_bytes``), those that came too ``late`` for their phase, ``malformed``
    ones, and the messages ``delivered`` to it and the bytes of its deliveries (``delivered_bytes``)."""

    FIELDS = ("sent", "sent_bytes", "late", "malformed", "delivered", "delivered_bytes")

    def __init__(self, num_robots: int):
        for f in self.FIELDS:
            setattr(self, f, np.zeros(num_robots, np.int64))

    def of(self, robot: int) -> dict[str, int]:
        return {f: int(getattr(self, f)[robot]) for f in self.FIELDS}

    def total(self) -> dict[str, int]:
        return {f: int(getattr(self, f).sum()) for f in self.FIELDS}


class Radio:
    """The radio of ``network`` (one episode of :class:`madp.sim.network.Network`) for tokens of
    ``token_dim`` values and cost messages of ``costs`` values (None: no cost round)."""

    def __init__(self, network: Network, token_dim: int, costs: int | None = None):
        self.network, self.token_dim, self.costs = network, int(token_dim), costs
        self.counts = {ch: ChannelCounts(network.num_robots) for ch in CHANNELS}

    def accept(self, channel: str, robot: int, message: Message, size_bytes: int) -> bool:
        """Whether robot ``robot``'s ``message`` (``size_bytes`` on the wire) can go on ``channel``:
        its sender is ``robot`` and, on ``token``, its token has ``token_dim`` values (on ``cost``, its
        costs ``costs``). Counts it."""
        c = self.counts[channel]
        size = {"token": self.token_dim, "cost": self.costs}.get(channel)
        ok = int(message.sender) == robot and (channel == "position" or (message.token is not None and size is not None
                                                                         and message.token.shape == (size,)))
        if ok:
            c.sent[robot] += 1
            c.sent_bytes[robot] += size_bytes
        else:
            c.malformed[robot] += 1
        return ok

    def late(self, channel: str, robot: int) -> None:
        self.counts[channel].late[robot] += 1

    def exchange(self, channel: str, step: int, sent: dict[int, Message]) -> list[list[Message]]:
        """What each robot hears on ``channel`` at ``step`` when ``sent`` (robot -> its accepted message
        of this step) reached the radio: ``[N]`` lists of :class:`Message`, ascending by sender."""
        n = self.network.num_robots
        width = 2 if channel == "position" else 2 + self.token_dim
        payload = np.zeros((n, width))
        senders = np.zeros(n, bool)
        for i, m in sent.items():
            payload[i, :2] = m.position_m
            if width > 2:
                payload[i, 2:] = m.token
            senders[i] = True
        return self.network.exchange(channel, step, payload, senders).messages()

    def relay(self, sent: dict[int, Message], holders: list[set[int]]) -> list[list[Message]]:
        """The cost round: for each robot i, the cost messages of ``sent`` (robot -> its accepted
        message of this step) whose senders are among ``holders[i]`` (the robots whose beacons i holds
        at this step), ascending by sender."""
        return [[sent[j] for j in sorted(sent) if j in held and j != i] for i, held in enumerate(holders)]

    def delivered(self, channel: str, robot: int, count: int, size_bytes: int) -> None:
        c = self.counts[channel]
        c.delivered[robot] += count
        c.delivered_bytes[robot] += size_bytes
