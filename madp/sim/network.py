"""The network between the robots: what each robot has received, over links that lose and delay messages.

Every robot holds only what it knows: its own sensed map, its own position estimate, and an inbox of
the messages it has received. A :class:`Message` carries the sender's id, the step at which it was
sent, the position the sender reported (its own estimate) and, for MADP, its token; LPAC-K3's graph
rounds send :class:`HopMessage`\\ s (one round of messages per hop of every graph layer).

:class:`NetworkSettings` names what the network does; :class:`Network` is one episode of it, owned by
the environment (:class:`madp.sim.CoverageEnv` ``network=``), so every controller, ``madp rollout``,
``madp eval`` and the environments see the same network:

* **range**: a message reaches only robots closer than r_c to the sender (true positions at the
  step it was sent);
* **loss**: each message on each link, in each round of messages, is lost with probability
  ``loss`` (i.i.d.);
* **delay**: a message sent at step s arrives at step s + ``delay_steps``;
* **the buffer** (one slot per sender and channel): ``missing="keep"`` keeps the last message
  received from a sender until it is older than ``max_age_steps`` steps since it was sent (then it
  is dropped; default: the delay, so nothing outlives the step the next message is due);
  ``missing="drop"`` holds only what arrived at this step. A robot cannot tell a lost message from
  a sender that left its range: a kept message stays until it is too old either way;
* **failures**: ``fail_fraction`` of the robots (drawn from the seed) stop at step ``fail_step``:
  they no longer move, sense or send, and the coverage cost counts only the survivors
  (:meth:`Network.fail` stops one more robot from a step on: a robot process that died);
* **position noise**: each robot's estimate of its own position is the true one plus Gaussian noise
  of ``position_noise_m`` per axis, drawn afresh at every step; it is what the robot uses (its
  window, its boundary, its neighbours' offsets, its goal) and what it reports. The sensor's
  readings land where they are: the importance map is geo-referenced.

Channels: ``position`` (every robot's beacon: its reported position, sent by the environment at
every step), ``token`` (MADP: position and token), ``lpac/R`` (LPAC-K3's graph round R). Each
(channel, step) draws its own losses, so the same seed gives the same run whatever the controller.
With the default settings the network is ideal: every message within range arrives at once, and
each robot's inbox holds exactly its neighbours' current states.
"""

from __future__ import annotations

import zlib
from dataclasses import asdict, dataclass, fields

import numpy as np

from madp.errors import SettingError

#: The buffer's rules for a sender whose message did not arrive at this step.
MISSING_RULES = ("keep", "drop")


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


@dataclass(frozen=True)
class NetworkSettings:
    """What the network between the robots does (module docstring). The defaults are ideal."""

    loss: float = 0.0
    delay_steps: int = 0
    max_age_steps: int | None = None
    missing: str = "keep"
    fail_fraction: float = 0.0
    fail_step: int = 200
    position_noise_m: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        def whole(name: str, low: int) -> int:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise SettingError(name, f"expected a whole number >= {low}, got {v!r}")
            return int(v)

        for name in ("loss", "fail_fraction"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
                raise SettingError(name, f"expected a probability in [0, 1], got {v!r}")
        v = self.position_noise_m
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v < float("inf"):
            raise SettingError("position_noise_m", f"expected a standard deviation >= 0 m, got {v!r}")
        whole("delay_steps", 0)
        whole("fail_step", 0)
        whole("seed", 0)
        if self.max_age_steps is not None and whole("max_age_steps", 0) < self.delay_steps:
            raise SettingError("max_age_steps", f"expected at least the delay ({self.delay_steps} steps): every "
                               f"message would be too old on arrival, got {self.max_age_steps}")
        if self.missing not in MISSING_RULES:
            raise SettingError("missing", f"expected one of {', '.join(MISSING_RULES)}, got {self.missing!r}")

    @property
    def max_age(self) -> int:
        """Steps a buffered message may have aged since it was sent (``max_age_steps``, default the delay)."""
        return self.delay_steps if self.max_age_steps is None else int(self.max_age_steps)

    @property
    def ideal(self) -> bool:
        """True when every robot holds exactly its neighbours' current states: every message within
        range arrives at once, none is kept past its step, no robot fails and none is lost."""
        return (self.loss == 0 and self.delay_steps == 0 and self.max_age == 0 and self.fail_fraction == 0
                and self.position_noise_m == 0)

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def parse(cls, text: str) -> "NetworkSettings":
        """Settings from ``"loss=0.3,delay_steps=5,missing=drop"`` (fields of this class; the rest default)."""
        types = {f.name: f.type for f in fields(cls)}
        values: dict = {}
        for item in filter(None, (t.strip() for t in text.split(","))):
            name, eq, value = item.partition("=")
            name = name.strip()
            if not eq or name not in types:
                raise SettingError("network", f"expected NAME=VALUE items with NAME one of {', '.join(types)}, got {item!r}")
            try:
                values[name] = value.strip() if name == "missing" else (
                    float(value) if "float" in types[name] else int(value))
            except ValueError:
                raise SettingError("network", f"{name}: expected a number, got {value.strip()!r}") from None
        return cls(**values)


@dataclass(frozen=True)
class Received:
    """One channel's inbox of every robot at one step: ``valid [N, N]`` bool (robot i holds a message
    from robot j; never i = j), ``payload [N, N, F]`` (its content, 0 where not valid) and
    ``sent_step [N, N]`` int64 (the step it was sent, -1 where not valid)."""

    valid: np.ndarray
    payload: np.ndarray
    sent_step: np.ndarray


#: What happened on each link at a step (:meth:`Network.links`).
LINK_OUT_OF_RANGE, LINK_DELIVERED, LINK_LOST, LINK_KEPT = 0, 1, 2, 3


class _Channel:
    """One channel's ring of sent payloads (by step) and every receiver's buffer (the step of the
    message it holds from each sender)."""

    def __init__(self, ring: int, n: int, width: int):
        self.payload = np.zeros((ring, n, width))
        self.sent = np.full(ring, -1, dtype=np.int64)  # the step each ring slot holds
        self.senders = np.ones((ring, n), dtype=bool)  # which robots sent in each ring slot
        self.stamps = np.full((n, n), -1, dtype=np.int64)
        self.processed = -1  # arrivals are applied up to this step
        self.links = np.zeros((n, n), dtype=np.int8)


class Network:
    """One episode of the network among ``num_robots`` robots (module docstring). The environment
    calls :meth:`record` at every step with the true positions; controllers call :meth:`exchange`
    once per channel and step with what every robot sends."""

    def __init__(self, settings: NetworkSettings, num_robots: int, comm_radius_m: float, world_size: int, seed: int):
        self.settings, self.num_robots, self.comm_radius_m = settings, int(num_robots), float(comm_radius_m)
        self.world_size = float(world_size)
        self.seed = int(np.random.SeedSequence([int(seed) & ((1 << 63) - 1), settings.seed]).generate_state(1)[0])
        self.ring = settings.max_age + 1
        n = self.num_robots
        k = int(round(settings.fail_fraction * n))
        failed = np.zeros(n, dtype=bool)
        failed[np.random.default_rng([self.seed, 0xFA11]).permutation(n)[:k]] = True
        self.failed = failed  # [N] bool: the robots that stop at some step
        self._stops_at = np.where(failed, settings.fail_step, np.iinfo(np.int64).max)  # [N]: the step each stops
        self._true = np.zeros((self.ring, n, 2))
        self._true_step = np.full(self.ring, -1, dtype=np.int64)
        self._channels: dict[str, _Channel] = {}

    # --- the robots ---------------------------------------------------------------------------------
    def alive(self, step: int) -> np.ndarray:
        """[N] bool: the robots still running at ``step``."""
        return step < self._stops_at

    def fail(self, robot: int, step: int) -> None:
        """Robot ``robot`` stops at ``step`` (or at its earlier failure): from then on it neither moves nor
        sends, and what it holds is dropped, as a robot of ``fail_fraction``."""
        self.failed[robot] = True
        self._stops_at[robot] = min(int(self._stops_at[robot]), int(step))

    def estimates(self, step: int, true_m: np.ndarray) -> np.ndarray:
        """[N, 2]: each robot's estimate of its own position at ``step``: ``true_m`` plus the noise, kept
        inside the world as positions are (1e-4 m from its border); ``true_m`` itself without noise."""
        sigma = self.settings.position_noise_m
        if sigma == 0:
            return true_m
        rng = np.random.default_rng([self.seed, int(step), 0x0015E])
        return np.clip(true_m + rng.normal(0.0, sigma, true_m.shape), 1e-4, self.world_size - 1e-4)

    def record(self, step: int, true_m: np.ndarray) -> None:
        """The true positions [N, 2] at ``step`` (they decide which links are in range)."""
        self._true[step % self.ring] = true_m
        self._true_step[step % self.ring] = step

    # --- messages -----------------------------------------------------------------------------------
    def in_range(self, step: int) -> np.ndarray:
        """[N, N] bool: receiver i and sender j closer than r_c at ``step`` (true positions; i ≠ j)."""
        x = self._true[step % self.ring]
        if self._true_step[step % self.ring] != step:
            raise ValueError(f"the network has no positions of step {step}")
        d = np.linalg.norm(x[:, None] - x[None], axis=2)
        return (d < self.comm_radius_m) & ~np.eye(self.num_robots, dtype=bool)

    def lost(self, channel: str, step: int) -> np.ndarray:
        """[N, N] bool: the messages of ``channel`` sent at ``step`` that the network loses (receiver i, sender j)."""
        n = self.num_robots
        if self.settings.loss == 0:
            return np.zeros((n, n), dtype=bool)
        rng = np.random.default_rng([self.seed, int(step), zlib.crc32(channel.encode())])
        return rng.random((n, n)) < self.settings.loss

    def exchange(self, channel: str, step: int, payload: np.ndarray, senders: np.ndarray | None = None) -> Received:
        """Every robot sends ``payload [N, F]`` on ``channel`` at ``step`` (failed robots send
        nothing; with ``senders [N]`` bool, only those robots send: the others' rows are ignored);
        returns what each robot holds on that channel after this step's arrivals. Which links lose a
        message does not depend on who sends."""
        payload = np.asarray(payload, dtype=np.float64)
        n, s = self.num_robots, self.settings
        ch = self._channels.get(channel)
        if ch is None or ch.payload.shape[2] != payload.shape[1]:
            ch = self._channels[channel] = _Channel(self.ring, n, payload.shape[1])
        slot = step % self.ring
        ch.payload[slot], ch.sent[slot] = payload, step
        ch.senders[slot] = True if senders is None else np.asarray(senders, dtype=bool)
        for t in range(ch.processed + 1, step + 1):  # every step's arrivals, in order
            ch.links[:] = LINK_OUT_OF_RANGE
            sent = t - s.delay_steps
            if sent >= 0 and ch.sent[sent % self.ring] == sent:
                sending = self.alive(sent) & ch.senders[sent % self.ring]
                reach = self.in_range(sent) & sending[None, :] & self.alive(t)[:, None]
                lost = self.lost(channel, sent) & reach
                arrived = reach & ~lost
                ch.stamps[arrived] = sent
                ch.links[arrived], ch.links[lost] = LINK_DELIVERED, LINK_LOST
            if s.missing == "drop":
                ch.stamps[ch.stamps != sent] = -1
            else:
                ch.stamps[(ch.stamps >= 0) & (t - ch.stamps > s.max_age)] = -1
                ch.links[(ch.stamps >= 0) & (ch.stamps < sent) & (ch.links == LINK_OUT_OF_RANGE)] = LINK_KEPT
            ch.stamps[~self.alive(t)] = -1  # a failed robot holds nothing
        ch.processed = step
        valid = ch.stamps >= 0
        i, j = np.nonzero(valid)
        out = np.zeros((n, n, payload.shape[1]))
        out[i, j] = ch.payload[ch.stamps[i, j] % self.ring, j]
        return Received(valid, out, np.where(valid, ch.stamps, -1))

    def links(self, channel: str = "position") -> np.ndarray:
        """[N, N] int8: what happened on each link (receiver i, sender j) of ``channel`` at the last
        step exchanged: :data:`LINK_DELIVERED`, :data:`LINK_LOST` (in range, lost), :data:`LINK_KEPT`
        (nothing new; an older message still buffered) or :data:`LINK_OUT_OF_RANGE` (nothing)."""
        ch = self._channels.get(channel)
        return np.zeros((self.num_robots,) * 2, np.int8) if ch is None else ch.links.copy()


__all__ = ["HopMessage", "LINK_DELIVERED", "LINK_KEPT", "LINK_LOST", "LINK_OUT_OF_RANGE", "MISSING_RULES",
           "Message", "Network", "NetworkSettings", "Received"]
