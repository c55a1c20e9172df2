"""The bytes between the processes of a swarm (``madp swarm``): small explicit binary records, and the
Zenoh keys and session settings they travel with. numpy and the standard library only (no torch).

Every record starts with the version byte :data:`VERSION` and a kind byte; numbers are little-endian,
arrays raw numpy buffers of a stated length. ``u32``/``u64`` unsigned, ``i32``/``i64`` signed,
``f32``/``f64`` IEEE floats:

=========  =================  ================================================================================
kind       direction          fields after (version, kind)
=========  =================  ================================================================================
HELLO 1    robot -> world     robot u32, pid u32 (sent every :data:`HELLO_INTERVAL_S` until START arrives)
START 2    world -> robot     robot u32, seed u64 (the swarm's shared seed, not the scenario's), max_age i32
                              (-1: no limit), flags u8 (bit 0: its position estimates are exact), n u32, n bytes
                              of UTF-8 JSON: the :class:`madp.sim.SimParams` fields of :data:`ROBOT_PARAMS`
                              (its sensor, its radio's range, its motion: :func:`robot_params`)
READY 3    robot -> world     robot u32 (its agent is built: the startup barrier)
STEP 4     world -> robot     flags u8 (bit 0: stop), robot u32, step u64, position_m f64[2] (its estimate),
                              lo_cell i64[2], s u32, values f32[s * s] (its sensor's reading, indexed [x, y])
SEND 5     robot -> radio     phase u8 (0 beacon, 1 token, 2 cost), sender u32, step u64, position_m f64[2],
                              d u32, token f32[d] (d = 0 for a beacon; a cost message's K costs)
DELIVER 6  radio -> robot     phase u8, robot u32, step u64, count u32, then count times:
                              sender u32, sent_step u64, position_m f64[2], d u32, token f32[d]
COMMAND 7  robot -> world     robot u32, step u64, action_mps f64[2] (world axes)
=========  =================  ================================================================================

:func:`decode` never raises: bytes that are not one whole record of this version (too short, too long,
an unknown kind, sizes beyond :data:`MAX_SIDE` / :data:`MAX_TOKEN` / :data:`MAX_COUNT`, a non-finite
position, reading, token, cost or action, bad UTF-8 or JSON) decode to None, so no packet can stop a
process. On the middleware every record is sealed with its robot's key (:mod:`madp.robot.seal`).

The cost phase is the round of the ``_joint`` selection rules (:attr:`madp.selection.Rule.joint`)
only: each robot's K costs of its candidates' copies, sent after it sampled and before its command.

Keys (``RUN`` a run's key, ``I`` a robot's id): the world publishes to ``madp/RUN/robot/I/in/<name>``
(``start``, ``step``, ``beacons``, ``tokens``, ``costs``) and subscribes to each ``madp/RUN/robot/I/out/*``;
robot I subscribes to ``madp/RUN/robot/I/in/*`` only and publishes to ``madp/RUN/robot/I/out/<name>``
(``hello``, ``ready``, ``beacon``, ``token``, ``cost``, ``cmd``). Sessions (:func:`zenoh_config`): peer mode,
multicast and gossip scouting off; the world listens on one loopback endpoint, each robot connects to
it and listens nowhere, so robots reach each other only through the world's radio. A robot logs in
with its user name and password (:func:`madp.robot.seal.transport_password`); the world's access
rules let robot I subscribe to its own ``in`` keys and publish on its own ``out`` keys only.
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass
from typing import Optional

import numpy as np

from madp.errors import SettingError
from madp.sim.network import Message

__all__ = ["COMMAND", "Command", "DELIVER", "Delivery", "HELLO", "HELLO_INTERVAL_S", "Hello", "PHASES", "PHASE_BEACON",
           "PHASE_COST", "PHASE_TOKEN", "READY", "ROBOT_PARAMS", "Ready", "SEND", "START", "STEP", "STOP", "Sent", "Start", "StepPacket", "VERSION",
           "check_endpoint", "check_run_key", "decode", "encode_command", "encode_delivery", "encode_hello",
           "encode_ready", "encode_send", "encode_start", "encode_step", "encode_stop", "in_key", "out_key", "robot_of",
           "robot_params",
           "zenoh_config"]

#: The record format's version: the first byte of every record.
VERSION = 2
HELLO, START, READY, STEP, SEND, DELIVER, COMMAND = 1, 2, 3, 4, 5, 6, 7
#: The radio's phases of a control step: position beacons, then tokens, then (``_joint`` rules) costs.
PHASE_BEACON, PHASE_TOKEN, PHASE_COST = 0, 1, 2
PHASES = ("beacon", "token", "cost")
#: Largest sensor side s, token size d and number of delivered messages a record may hold.
MAX_SIDE, MAX_TOKEN, MAX_COUNT = 4096, 65536, 1 << 20
#: The :class:`madp.sim.SimParams` fields a START carries: what a robot's own sensor, radio and motion
#: give it (never the fields that, with a seed, rebuild the world's features).
ROBOT_PARAMS = ("world_size", "comm_radius_m", "sensor_size", "local_map_size", "obs_size", "max_speed_mps", "dt_s",
                "history_size", "check_oscillations")
#: Seconds between a starting robot's HELLOs.
HELLO_INTERVAL_S = 0.2
#: Flag bit of a STEP record: the world ends the run (the robot exits).
STOP = 1

_HEAD = struct.Struct("<BB")
_HELLO = struct.Struct("<BBII")
_START = struct.Struct("<BBIQiBI")
_READY = struct.Struct("<BBI")
_STEP = struct.Struct("<BBBIQ2d2qI")
_SEND = struct.Struct("<BBBIQ2dI")
_DELIVER = struct.Struct("<BBBIQI")
_ITEM = struct.Struct("<IQ2dI")
_COMMAND = struct.Struct("<BBIQ2d")
_U64 = (1 << 64) - 1


@dataclass(frozen=True)
class Hello:
    robot: int
    pid: int


@dataclass(frozen=True)
class Start:
    """The run's settings for one robot: ``seed`` (the episode's), ``max_age`` (the oldest messages its
    runtime uses, in steps; None: no limit), ``params`` (the scenario's SimParams as a dict) and
    ``exact_position`` (its position estimates are its true positions: no localisation noise)."""

    robot: int
    seed: int
    max_age: Optional[int]
    params: dict
    exact_position: bool = True


@dataclass(frozen=True)
class Ready:
    robot: int


@dataclass(frozen=True)
class StepPacket:
    """Control step ``step`` of robot ``robot``: its position estimate ``position_m [2]`` and its sensor's
    reading (``lo_cell [2]`` int64, ``values [s, s]`` float32); ``stop``: the run is over."""

    robot: int
    step: int
    position_m: np.ndarray
    lo_cell: np.ndarray
    values: np.ndarray
    stop: bool = False


@dataclass(frozen=True)
class Sent:
    """A robot's broadcast of one phase (``message.token`` None for a beacon)."""

    phase: int
    message: Message


@dataclass(frozen=True)
class Delivery:
    """What robot ``robot``'s radio delivered in ``phase`` of control step ``step``."""

    phase: int
    robot: int
    step: int
    messages: list


@dataclass(frozen=True)
class Command:
    robot: int
    step: int
    action_mps: np.ndarray


# --- encoding -------------------------------------------------------------------------------------------
def encode_hello(robot: int, pid: int) -> bytes:
    return _HELLO.pack(VERSION, HELLO, int(robot), int(pid) & 0xFFFFFFFF)


def robot_params(params: dict) -> dict:
    """The :data:`ROBOT_PARAMS` fields of ``params`` (a ``SimParams.to_dict``)."""
    return {k: params[k] for k in ROBOT_PARAMS if k in params}


def encode_start(robot: int, seed: int, max_age: Optional[int], params: dict, exact_position: bool = True) -> bytes:
    """A START record: ``params`` cut to :data:`ROBOT_PARAMS` (:func:`robot_params`)."""
    text = json.dumps(robot_params(params), sort_keys=True).encode()
    age = -1 if max_age is None else int(max_age)
    return _START.pack(VERSION, START, int(robot), int(seed) & _U64, age, int(bool(exact_position)), len(text)) + text


def encode_ready(robot: int) -> bytes:
    return _READY.pack(VERSION, READY, int(robot))


def encode_step(robot: int, step: int, position_m: np.ndarray, lo_cell: np.ndarray, values: np.ndarray,
                stop: bool = False) -> bytes:
    """A STEP record: ``values [s, s]`` (float32, indexed [x, y]); a stop record may carry ``s = 0``."""
    v = np.ascontiguousarray(values, dtype="<f4")
    s = int(v.shape[0]) if v.size else 0
    px, py = (float(x) for x in np.asarray(position_m, np.float64).reshape(2))
    lx, ly = (int(x) for x in np.asarray(lo_cell).reshape(2))
    return _STEP.pack(VERSION, STEP, STOP if stop else 0, int(robot), int(step), px, py, lx, ly, s) + v.tobytes()


def encode_stop(robot: int, step: int) -> bytes:
    """The STEP record that ends the run."""
    return encode_step(robot, step, np.zeros(2), np.zeros(2, np.int64), np.zeros((0, 0), np.float32), stop=True)


def _item(message: Message) -> tuple[tuple, bytes]:
    tok = np.zeros(0, "<f4") if message.token is None else np.ascontiguousarray(message.token, dtype="<f4").reshape(-1)
    px, py = (float(x) for x in np.asarray(message.position_m, np.float64).reshape(2))
    return (int(message.sender), int(message.step), px, py, len(tok)), tok.tobytes()


def encode_send(phase: int, message: Message) -> bytes:
    """A SEND record: robot ``message.sender``'s beacon (token None), token or costs of ``phase``."""
    (sender, step, px, py, d), tok = _item(message)
    return _SEND.pack(VERSION, SEND, int(phase), sender, step, px, py, d) + tok


def encode_delivery(phase: int, robot: int, step: int, messages: list) -> bytes:
    """A DELIVER record: the :class:`Message`\\ s robot ``robot``'s radio delivered in ``phase`` of ``step``."""
    parts = [_DELIVER.pack(VERSION, DELIVER, int(phase), int(robot), int(step), len(messages))]
    for m in messages:
        fields, tok = _item(m)
        parts += [_ITEM.pack(*fields), tok]
    return b"".join(parts)


def encode_command(robot: int, step: int, action_mps: np.ndarray) -> bytes:
    ux, uy = (float(x) for x in np.asarray(action_mps, np.float64).reshape(2))
    return _COMMAND.pack(VERSION, COMMAND, int(robot), int(step), ux, uy)


# --- decoding -------------------------------------------------------------------------------------------
def _finite(*values: float) -> bool:
    return all(np.isfinite(values))


def _f32(buf: memoryview, offset: int, count: int) -> np.ndarray:
    return np.frombuffer(buf, dtype="<f4", count=count, offset=offset).astype(np.float32)


def _decode(buf: memoryview):
    version, kind = _HEAD.unpack_from(buf)
    if version != VERSION:
        return None
    n = len(buf)
    if kind == HELLO and n == _HELLO.size:
        return Hello(*_HELLO.unpack(buf)[2:])
    if kind == READY and n == _READY.size:
        return Ready(_READY.unpack(buf)[2])
    if kind == COMMAND and n == _COMMAND.size:
        robot, step, ux, uy = _COMMAND.unpack(buf)[2:]
        return Command(robot, step, np.array([ux, uy])) if _finite(ux, uy) else None
    if kind == START and n >= _START.size:
        robot, seed, age, flags, length = _START.unpack_from(buf)[2:]
        if n != _START.size + length or age < -1 or flags > 1:
            return None
        params = json.loads(bytes(buf[_START.size:]).decode("utf-8"))
        if not isinstance(params, dict) or not set(params) <= set(ROBOT_PARAMS):
            return None
        return Start(robot, seed, None if age < 0 else age, params, bool(flags))
    if kind == STEP and n >= _STEP.size:
        flags, robot, step, px, py, lx, ly, s = _STEP.unpack_from(buf)[2:]
        if s > MAX_SIDE or n != _STEP.size + 4 * s * s or flags & ~STOP or not _finite(px, py):
            return None
        values = _f32(buf, _STEP.size, s * s).reshape(s, s)
        if not np.isfinite(values).all() or (s == 0 and not flags & STOP):
            return None
        return StepPacket(robot, step, np.array([px, py]), np.array([lx, ly], np.int64), values, bool(flags & STOP))
    if kind == SEND and n >= _SEND.size:
        phase, sender, step, px, py, d = _SEND.unpack_from(buf)[2:]
        if phase >= len(PHASES) or d > MAX_TOKEN or n != _SEND.size + 4 * d or not _finite(px, py):
            return None
        token = _f32(buf, _SEND.size, d) if phase != PHASE_BEACON else None
        if (phase == PHASE_BEACON and d) or (token is not None and not np.isfinite(token).all()):
            return None
        return Sent(phase, Message(sender, step, np.array([px, py]), token))
    if kind == DELIVER and n >= _DELIVER.size:
        phase, robot, step, count = _DELIVER.unpack_from(buf)[2:]
        if phase >= len(PHASES) or count > MAX_COUNT or n < _DELIVER.size + count * _ITEM.size:
            return None
        at, messages = _DELIVER.size, []
        for _ in range(count):
            sender, sent, px, py, d = _ITEM.unpack_from(buf, at)
            at += _ITEM.size
            if d > MAX_TOKEN or n < at + 4 * d or not _finite(px, py):
                return None
            token = _f32(buf, at, d) if phase != PHASE_BEACON else None
            if (phase == PHASE_BEACON and d) or (token is not None and not np.isfinite(token).all()):
                return None
            at += 4 * d
            messages.append(Message(sender, sent, np.array([px, py]), token))
        return Delivery(phase, robot, step, messages) if at == n else None
    return None


def decode(data) -> object | None:
    """The record ``data`` (bytes-like) holds: a :class:`Hello`, :class:`Start`, :class:`Ready`,
    :class:`StepPacket`, :class:`Sent`, :class:`Delivery` or :class:`Command`; None for anything else.
    Never raises."""
    try:
        return _decode(memoryview(data).cast("B"))
    except Exception:  # struct.error, ValueError, UnicodeDecodeError, RecursionError, ... of junk
        return None


# --- keys and sessions ----------------------------------------------------------------------------------
_RUN_KEY = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_ENDPOINT = re.compile(r"^(tcp|udp|quic|tls|unixsock-stream)/\S+$")


def check_run_key(key: str) -> str:
    """``key`` if it is a run key (1 to 64 letters, digits, ``-`` or ``_``), else a SettingError."""
    if not isinstance(key, str) or not _RUN_KEY.match(key):
        raise SettingError("key", f"expected 1 to 64 letters, digits, - or _, got {key!r}")
    return key


def check_endpoint(endpoint: str) -> str:
    """``endpoint`` if it is a Zenoh endpoint such as ``tcp/127.0.0.1:7447``, else a SettingError."""
    if not isinstance(endpoint, str) or not _ENDPOINT.match(endpoint):
        raise SettingError("endpoint", f"expected a Zenoh endpoint such as tcp/127.0.0.1:7447, got {endpoint!r}")
    return endpoint


def in_key(run_key: str, robot: int | str, name: str) -> str:
    """``madp/RUN/robot/I/in/NAME``: what robot I receives (``*`` for NAME: all of it)."""
    return f"madp/{run_key}/robot/{robot}/in/{name}"


def out_key(run_key: str, robot: int | str, name: str) -> str:
    """``madp/RUN/robot/I/out/NAME``: what robot I sends."""
    return f"madp/{run_key}/robot/{robot}/out/{name}"


def robot_of(key: str) -> int | None:
    """The robot id of an ``out`` key (None when the key is not one)."""
    parts = str(key).split("/")
    return int(parts[3]) if len(parts) == 6 and parts[3].isdigit() else None


def zenoh_config(listen: str | None = None, connect: str | None = None, login: tuple[str, str] | None = None,
                 users_file: str | None = None, access: dict | None = None):
    """A Zenoh session's settings: peer mode, no multicast or gossip scouting, listening on ``listen``
    only (or nowhere) and connecting to ``connect`` only (or nowhere). ``login``: the (user, password)
    it gives the peers it opens; ``users_file``: the ``user:password`` lines of the peers it accepts
    (no others); ``access``: its ``access_control`` settings."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([listen] if listen else []))
    conf.insert_json5("connect/endpoints", json.dumps([connect] if connect else []))
    if login is not None:
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(login[0]))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(login[1]))
    if users_file is not None:
        conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(users_file)))
    if access is not None:
        conf.insert_json5("access_control", json.dumps(access))
    return conf
