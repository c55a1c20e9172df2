"""The network between the robots: what each robot has received, over links that lose and delay messages.

Every robot holds only what it knows: its own sensed map, its own position estimate, and an inbox of
the messages it has received. A :class:`Message` carries the sender's id, the step at which it was
sent, the position the sender reported (its own estimate) and, for MADP, its token; LPAC-K3's graph
rounds send :class:`HopMessage`\\ s (one round of messages per hop of every graph layer).

:class:`NetworkSettings` names what the network does; :class:`Network` is one episode of it, owned by
the environment (:class:`madp.sim.CoverageEnv` ``network=``), so every controller, ``madp rollout``,
``madp eval`` and the environments see the same network:

* **range**: a message reaches only robots closer than r_c to the sender (true positions at the
  step it was sent; :func:`madp.sim.rules.closer_than`);
* **loss**: each message on each link, in each round of messages, is lost with probability
  ``loss``, i.i.d.; with ``burst_len`` ≥ 1 the losses come in bursts instead (Gilbert–Elliott, below);
* **loss with distance**: a message on a link of length d is also lost with probability
  ``loss_at_range`` · (d / r_c)²: 0 between robots at the same place, rising with the square of the
  distance (the power a radio receives falls with it) to ``loss_at_range`` at r_c. It is drawn
  independently of ``loss``: an i.i.d. message is lost with 1 − (1 − loss)(1 − p(d)); in a burst's
  good state with p(d);
* **delay**: a message sent at step s arrives at step s + ``delay_steps``;
* **the buffer** (one slot per sender and channel): ``missing="keep"`` keeps the last message
  received from a sender until it is older than ``max_age_steps`` steps since it was sent (then it
  is dropped; default: the delay, so nothing outlives the step the next message is due);
  ``missing="drop"`` holds only what arrived at this step. A robot cannot tell a lost message from
  a sender that left its range: a kept message stays until it is too old either way;
* **bandwidth**: with ``max_bytes_per_step`` each robot puts at most that many bytes on the air per
  step, over every channel together. Messages go first come, first sent: the position beacon (the
  environment sends it as the step begins), then the controller's channels in the order it sends
  them (MADP: its ``token``; LPAC-K3: its rounds ``lpac/0``, ``lpac/1``, …). A message that would
  exceed what is left is not sent (a later, smaller one still may be); a receiver then holds what
  its buffer kept;
* **failures**: ``fail_fraction`` of the robots (drawn from the seed) stop at step ``fail_step``:
  they no longer move, sense or send, and the coverage cost counts only the survivors
  (:meth:`Network.fail` stops one more robot from a step on: a robot process that died). A team
  with no survivor is refused: its cost would read as a perfect 0;
* **position noise**: each robot's estimate of its own position is the true one plus Gaussian noise
  of ``position_noise_m`` per axis, drawn afresh at every step; it is what the robot uses (its
  window, its boundary, its neighbours' offsets, its goal) and what it reports. The sensor's
  readings land where they are: the importance map is geo-referenced.

**Bursts** (``burst_len`` = b ≥ 1, the Gilbert case of the Gilbert–Elliott channel): every link
(receiver i, sender j) of every channel is, at every step, in a good state (its message arrives,
distance aside) or a bad one (its message is lost). A bad link turns good with probability 1/b per
step, so a burst lasts b steps on average (b rounds of that channel: a channel sends once per step);
a good link turns bad with probability (1/b) · loss / (1 − loss), so a link is bad a share ``loss``
of the time, the mean loss of the i.i.d. setting (b ≥ loss / (1 − loss) keeps that a probability).
A link starts at step 0 in the bad state with probability ``loss``. The state belongs to the link,
not to a channel: a link in a burst loses everything sent on it at that step, on every channel (the
position beacon, the token, and all of LPAC-K3's rounds ``lpac/R`` inside the step alike), as a radio
link in a fade does.

**Bytes on the air** (:func:`message_bytes`, :meth:`Network.bytes_sent`): a message is counted once
per sender, whatever the number of its receivers (a broadcast), with the size of ``madp swarm``'s
SEND record (:mod:`madp.robot.wire`): a header of :data:`HEADER_BYTES` (version, kind, phase u8 each,
sender u32, step u64, value count u32), then on the ``position`` and ``token`` channels the
position as float64 [2] and every other value as float32, on the other channels every value as
float32: a beacon is 35 bytes, MADP's token message 35 + 4 · 34, an LPAC-K3 round 19 + 4 · F for F
features. A robot that does not send (failed, silent or over its budget) puts nothing on the air;
:meth:`Network.bytes_per_robot_step` averages over the steps of the robots still running.

Channels: ``position`` (every robot's beacon: its reported position, sent by the environment at
every step), ``token`` (MADP: position and token), ``lpac/R`` (LPAC-K3's graph round R). Each
(channel, step) draws its own losses, so the same seed gives the same run whatever the controller.
With the default settings the network is ideal: every message within range arrives at once, and
each robot's inbox holds exactly its neighbours' current states.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import asdict, dataclass, fields
from functools import cached_property

import numpy as np

from madp.errors import SettingError

from .rules import closer_than, distances_m

#: The buffer's rules for a sender whose message did not arrive at this step.
MISSING_RULES = ("keep", "drop")
#: The largest ``delay_steps`` and ``max_age_steps``: 100 000 steps (5.6 h of 0.2 s steps), far beyond
#: any episode; a larger value is a mistake, refused before anything runs.
MAX_NETWORK_STEPS = 100_000
#: Bytes of a message's header on the air (module docstring): version, kind, phase u8, sender u32,
#: step u64, value count u32.
HEADER_BYTES = 19
#: The channels whose payload starts with the sender's reported position (float64 on the air).
POSITION_CHANNELS = ("position", "token")


def message_bytes(channel: str, width: int) -> int:
    """Bytes on the air of one message of ``channel`` carrying ``width`` values (module docstring)."""
    if channel in POSITION_CHANNELS and width >= 2:
        return HEADER_BYTES + 8 * 2 + 4 * (int(width) - 2)
    return HEADER_BYTES + 4 * int(width)


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
    burst_len: float = 0.0  # 0: i.i.d. losses; b >= 1: bursts of b steps on average (Gilbert-Elliott)
    loss_at_range: float = 0.0  # the loss that distance adds at r_c (rising as (d / r_c)^2)
    max_bytes_per_step: int | None = None  # each robot's bytes on the air per step (None: no limit)

    def __post_init__(self) -> None:
        def whole(name: str, low: int, high: int | None = None, what: str = "") -> int:
            v = getattr(self, name)
            if (isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low
                    or (high is not None and v > high)):
                bound = f">= {low}" if high is None else f"in [{low}, {high}]"
                raise SettingError(name, f"expected a whole number {bound}{what}, got {v!r}")
            return int(v)

        def number(name: str) -> float:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise SettingError(name, f"expected a number, got {v!r}")
            return float(v)

        for name in ("loss", "loss_at_range"):
            if not 0.0 <= number(name) <= 1.0:
                raise SettingError(name, f"expected a probability in [0, 1], got {getattr(self, name)!r}")
        if not 0.0 <= number("fail_fraction") < 1.0:
            raise SettingError("fail_fraction", "expected a fraction in [0, 1) (at 1 no robot survives to be scored), "
                                                f"got {self.fail_fraction!r}")
        if not 0.0 <= number("position_noise_m") < math.inf:
            raise SettingError("position_noise_m",
                               f"expected a standard deviation >= 0 m, got {self.position_noise_m!r}")
        b = number("burst_len")
        if not (b == 0 or 1 <= b < math.inf):
            raise SettingError("burst_len", f"expected 0 (i.i.d. losses) or a mean burst length >= 1 step, got {b!r}")
        if b and self.loss > b / (1 + b):
            raise SettingError("burst_len", f"with loss {self.loss} a good link must turn bad with probability "
                                            f"loss / ((1 - loss) burst_len) <= 1: expected burst_len >= "
                                            f"{self.loss / (1 - self.loss):.4g} (and loss < 1), got {b!r}")
        span = f" (steps; {MAX_NETWORK_STEPS} steps of 0.2 s are 5.6 h)"
        whole("delay_steps", 0, MAX_NETWORK_STEPS, span)
        whole("fail_step", 0)
        whole("seed", 0)
        if self.max_age_steps is not None and whole("max_age_steps", 0, MAX_NETWORK_STEPS, span) < self.delay_steps:
            raise SettingError("max_age_steps", f"expected at least the delay ({self.delay_steps} steps): every "
                               f"message would be too old on arrival, got {self.max_age_steps}")
        if self.max_bytes_per_step is not None:
            whole("max_bytes_per_step", 0, what=" (bytes per robot per step)")
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
                and self.position_noise_m == 0 and self.loss_at_range == 0 and self.max_bytes_per_step is None)

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def parse(cls, text: str) -> "NetworkSettings":
        """Settings from ``"loss=0.3,delay_steps=5,missing=drop"`` (fields of this class, each at most once;
        the rest default). Any other text is a :class:`SettingError` of setting ``network`` naming the item."""
        types = {f.name: f.type for f in fields(cls)}
        expected = f"NAME=VALUE items separated by commas, NAME one of {', '.join(types)}"
        items = [t.strip() for t in str(text).split(",")]
        if not any(items):
            raise SettingError("network", f"expected {expected}, got {text!r}")
        values: dict = {}
        for item in items:
            name, eq, value = item.partition("=")
            name = name.strip()
            if not eq or name not in types:
                where = f" in {text!r}" if item != text else ""
                raise SettingError("network", f"expected {expected}, got {item!r}{where}")
            if name in values:
                raise SettingError("network", f"{name} is given twice in {text!r}")
            real = "float" in types[name]
            try:
                values[name] = value.strip() if name == "missing" else float(value) if real else int(value)
            except ValueError:
                raise SettingError("network", f"{name}: expected a {'number' if real else 'whole number'}, "
                                              f"got {value.strip()!r}") from None
        try:
            return cls(**values)
        except SettingError as e:
            raise SettingError("network", str(e)) from None


@dataclass(frozen=True)
class Received:
    """One channel's inbox of every robot at one step: ``valid [N, N]`` bool (robot i holds a message
    from robot j; never i = j), ``sent_step [N, N]`` int64 (the step it was sent, -1 where not valid)
    and ``sent {step: [N, F]}`` (what every robot sent at each step some message held was sent;
    F = ``width``).
    ``payload [N, N, F]`` is the held content (0 where not valid), built when first read;
    :meth:`weighted_sum` reduces the inbox without building it."""

    valid: np.ndarray
    sent_step: np.ndarray
    sent: dict[int, np.ndarray]
    width: int

    @cached_property
    def payload(self) -> np.ndarray:
        n = len(self.valid)
        out = np.zeros((n, n, self.width))
        for t, rows in self.sent.items():
            i, j = np.nonzero(self.sent_step == t)
            out[i, j] = rows[j]
        return out

    def weighted_sum(self, weights: np.ndarray) -> np.ndarray:
        """``[N, F]``: row i is the sum over held messages j of ``weights[i, j]`` times their content
        (``weights [N, N]``; entries where nothing is held count nothing)."""
        out = np.zeros((len(self.valid), self.width))
        for t, rows in self.sent.items():
            held = self.sent_step == t
            senders = held.any(axis=0)  # only held content enters the sum (a sender's other rows may be anything)
            out += np.where(held, weights, 0.0)[:, senders] @ rows[senders]
        return out

    def messages(self) -> list[list[Message]]:
        """Each robot's held messages as :class:`Message`\\ s ``(sender, step sent, position, token)``,
        ascending by sender, for a payload of ``[position_m (2), token (D)]`` per message (D = 0: position
        beacons, token None; a token as float32)."""
        token = self.payload.shape[2] > 2
        return [[Message(int(j), int(self.sent_step[i, j]), self.payload[i, j, :2].copy(),
                         self.payload[i, j, 2:].astype(np.float32) if token else None)
                 for j in np.flatnonzero(self.valid[i])] for i in range(len(self.valid))]


#: What happened on each link at a step (:meth:`Network.links`).
LINK_OUT_OF_RANGE, LINK_DELIVERED, LINK_LOST, LINK_KEPT = 0, 1, 2, 3


class _Channel:
    """One channel's messages by the step they were sent (``sent``: payload [N, F] and which robots
    sent, kept while in flight or held by a receiver) and every receiver's buffer (the step of the
    message it holds from each sender)."""

    def __init__(self, n: int, width: int):
        self.width = width
        self.sent: dict[int, tuple[np.ndarray, np.ndarray]] = {}
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
        n = self.num_robots
        k = int(round(settings.fail_fraction * n))
        if n and k >= n:
            raise SettingError("network", f"fail_fraction: {settings.fail_fraction} of {n} robots fails all {n}: "
                                          "no robot would survive to be scored")
        failed = np.zeros(n, dtype=bool)
        failed[np.random.default_rng([self.seed, 0xFA11]).permutation(n)[:k]] = True
        self.failed = failed  # [N] bool: the robots that stop at some step
        self._stops_at = np.where(failed, settings.fail_step, np.iinfo(np.int64).max)  # [N]: the step each stops
        self._true: dict[int, np.ndarray] = {}  # step -> the true positions [N, 2] (as far back as the delay)
        self._range: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # step -> (its positions, in_range)
        self._channels: dict[str, _Channel] = {}
        self._bursts: dict[str, tuple[int, np.ndarray]] = {}  # "links" -> (step, the links' bad state [N, N])
        self._bytes: dict[str, dict[int, np.ndarray]] = {}  # channel -> step -> bytes each robot sent [N]
        self._spent = (-1, np.zeros(n, dtype=np.int64))  # (step, bytes each robot sent at it on every channel)

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
        """The true positions [N, 2] at ``step`` (they decide which links are in range and how long they are)."""
        self._true[int(step)] = np.array(true_m, dtype=np.float64)
        oldest = min([int(step)] + [ch.processed + 1 for ch in self._channels.values()]) - self.settings.delay_steps
        for t in [t for t in self._true if t < oldest]:
            del self._true[t]
        for t in [t for t in self._range if t not in self._true]:
            del self._range[t]

    # --- messages -----------------------------------------------------------------------------------
    def _positions(self, step: int) -> np.ndarray:
        x = self._true.get(int(step))
        if x is None:
            raise ValueError(f"the network has no positions of step {step}")
        return x

    def in_range(self, step: int) -> np.ndarray:
        """[N, N] bool: receiver i and sender j closer than r_c at ``step`` (true positions; i ≠ j).
        Every channel of a step reads the same links: computed once per step and kept with its positions."""
        x = self._positions(step)
        cached = self._range.get(int(step))
        if cached is None or cached[0] is not x:
            cached = (x, closer_than(x[:, None] - x[None], self.comm_radius_m) & ~np.eye(self.num_robots, dtype=bool))
            self._range[int(step)] = cached
        return cached[1].copy()

    def lost(self, channel: str, step: int) -> np.ndarray:
        """[N, N] bool: the messages of ``channel`` sent at ``step`` that the network loses (receiver i, sender j)."""
        n, s = self.num_robots, self.settings
        if s.loss == 0 and s.loss_at_range == 0:
            return np.zeros((n, n), dtype=bool)
        rng = np.random.default_rng([self.seed, int(step), zlib.crc32(channel.encode())])
        u = rng.random((n, n))
        far = 0.0
        if s.loss_at_range > 0:
            x = self._positions(step)
            far = s.loss_at_range * np.minimum(distances_m(x[:, None] - x[None]) / self.comm_radius_m, 1.0) ** 2
        if s.burst_len == 0:
            return u < (s.loss if s.loss_at_range == 0 else 1.0 - (1.0 - s.loss) * (1.0 - far))
        bad = self._bad(int(step)) if s.loss > 0 else np.zeros((n, n), dtype=bool)
        return bad | (u < far) if s.loss_at_range > 0 else bad

    def _bad(self, step: int) -> np.ndarray:
        """[N, N] bool: the links in the bad state at ``step``, on every channel (module docstring,
        bursts): the chain advanced step by step from step 0, each step's draw its own."""
        s, n = self.settings, self.num_robots
        leave = 1.0 / s.burst_len  # bad -> good
        enter = leave * s.loss / (1.0 - s.loss)  # good -> bad

        def draw(t: int) -> np.ndarray:
            return np.random.default_rng([self.seed, t, 0xB0257]).random((n, n))

        t, bad = self._bursts.get("links", (step + 1, None))
        if t > step:
            t, bad = 0, draw(0) < s.loss
        while t < step:
            t += 1
            u = draw(t)
            bad = np.where(bad, u >= leave, u < enter)
        self._bursts["links"] = (t, bad)
        return bad

    def _spend(self, channel: str, step: int, sending: np.ndarray, size: int) -> np.ndarray:
        """Which of ``sending [N]`` put their message of ``size`` bytes on the air at ``step`` within
        the budget (module docstring, bandwidth); counts their bytes (a second send of the same channel
        and step replaces the first's count)."""
        if self._spent[0] != step:
            self._spent = (step, np.zeros(self.num_robots, dtype=np.int64))
        spent = self._spent[1]
        per_step = self._bytes.setdefault(channel, {})
        if step in per_step:
            spent -= per_step[step]
        limit = self.settings.max_bytes_per_step
        if limit is not None:
            sending = sending & (spent + size <= limit)
        per_step[step] = np.where(sending, size, 0).astype(np.int64)
        spent += per_step[step]
        return sending

    def _arrive(self, ch: _Channel, channel: str, t: int) -> None:
        """Apply step ``t``'s arrivals on ``ch`` to every receiver's buffer and ``links``."""
        s = self.settings
        ch.links[:] = LINK_OUT_OF_RANGE
        sent = t - s.delay_steps
        msg = ch.sent.get(sent) if sent >= 0 else None
        if msg is not None:
            sending = self.alive(sent) & msg[1]
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

    def exchange(self, channel: str, step: int, payload: np.ndarray, senders: np.ndarray | None = None) -> Received:
        """Every robot sends ``payload [N, F]`` on ``channel`` at ``step`` (failed robots send
        nothing; with ``senders [N]`` bool, only those robots send: the others' rows are ignored; with
        a bandwidth limit, only those within their budget); returns what each robot holds on that
        channel after this step's arrivals. Which links lose a message does not depend on who sends."""
        payload = np.array(payload, dtype=np.float64)  # a copy: held until delivered and dropped
        n, step = self.num_robots, int(step)
        ch = self._channels.get(channel)
        if ch is None or ch.width != payload.shape[1]:
            ch = self._channels[channel] = _Channel(n, payload.shape[1])
        for t in range(ch.processed + 1, step):  # the arrivals of the steps this channel missed, in order
            self._arrive(ch, channel, t)
        sending = self.alive(step) & (True if senders is None else np.asarray(senders, dtype=bool))
        ch.sent[step] = (payload, self._spend(channel, step, sending, message_bytes(channel, payload.shape[1])))
        if step > ch.processed:
            self._arrive(ch, channel, step)
            ch.processed = step
        valid = ch.stamps >= 0
        held = set(np.unique(ch.stamps[valid]).tolist())
        ch.sent = {t: m for t, m in ch.sent.items() if t in held or t > ch.processed - self.settings.delay_steps}
        return Received(valid, np.where(valid, ch.stamps, -1), {t: ch.sent[t][0] for t in sorted(held)},
                        payload.shape[1])

    def links(self, channel: str = "position") -> np.ndarray:
        """[N, N] int8: what happened on each link (receiver i, sender j) of ``channel`` at the last
        step exchanged: :data:`LINK_DELIVERED`, :data:`LINK_LOST` (in range, lost), :data:`LINK_KEPT`
        (nothing new; an older message still buffered) or :data:`LINK_OUT_OF_RANGE` (nothing)."""
        ch = self._channels.get(channel)
        return np.zeros((self.num_robots,) * 2, np.int8) if ch is None else ch.links.copy()

    # --- bytes on the air ---------------------------------------------------------------------------
    def bytes_sent(self, steps: int) -> dict[str, np.ndarray]:
        """``{channel: [steps, N] int64}``: the bytes each robot put on the air on each channel at steps
        0 … steps − 1 (:func:`message_bytes` per message sent; 0 where it sent nothing)."""
        out = {}
        for channel, per_step in sorted(self._bytes.items()):
            a = np.zeros((int(steps), self.num_robots), dtype=np.int64)
            for t, b in per_step.items():
                if 0 <= t < steps:
                    a[t] = b
            out[channel] = a
        return out

    def bytes_per_robot_step(self, steps: int) -> dict[str, float]:
        """The mean bytes a running robot put on the air per step, over steps 0 … steps − 1 and the robots
        running at each (a failed robot's steps are not counted), per channel and in ``"total"`` (every
        channel together)."""
        sent = self.bytes_sent(steps)
        running = np.array([self.alive(t) for t in range(int(steps))], dtype=bool).reshape(-1, self.num_robots)
        count = max(int(running.sum()), 1)
        per = {ch: float(a[running].sum() / count) for ch, a in sent.items()}
        return {**per, "total": float(sum(a[running].sum() for a in sent.values()) / count)}

__all__ = ["HEADER_BYTES", "HopMessage", "LINK_DELIVERED", "LINK_KEPT", "LINK_LOST", "LINK_OUT_OF_RANGE",
           "MAX_NETWORK_STEPS", "MISSING_RULES", "Message", "Network", "NetworkSettings", "POSITION_CHANNELS",
           "Received", "message_bytes"]
