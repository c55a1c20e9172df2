"""The world's side of the middleware: one Zenoh session listening on a loopback endpoint, one
publisher per robot and ``in`` key, and one subscription per robot to what it sends
(:mod:`madp.robot.wire` has the keys and the records).

Who may speak (:mod:`madp.robot.seal`): the run has a fresh secret, and robot i a key derived from it.
The endpoint accepts only the robots' logins (user ``robotI`` and the password of its key, from a
users file only the world's user can read), and its access rules let robot I subscribe to its own
``in`` keys and publish on its own ``out`` keys only: a process without a robot's login cannot open
a session with the world, and a robot can neither hear another's keys nor publish on them. Every
record is sealed with its robot's key on the way out and checked on the way in: a record whose tag is
not its robot's arrives with ``data`` None (the world counts it as forged and never reads it).

What arrives is queued with the robot id its key names and the time it arrived
(``time.perf_counter()``, taken in Zenoh's callback); records are decoded by the caller's thread.
"""

from __future__ import annotations

import queue
import secrets
import shutil
import socket
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from madp.robot.seal import new_secret, robot_key, seal, transport_password, transport_user, unseal
from madp.robot.wire import in_key, out_key, robot_of, zenoh_config

__all__ = ["Arrival", "WorldBus", "access_rules", "free_endpoint", "IN_NAMES"]

#: What the world sends each robot, by key name (``madp/RUN/robot/I/in/NAME``).
IN_NAMES = ("start", "step", "beacons", "tokens", "costs")


@dataclass(frozen=True)
class Arrival:
    """One record on robot ``robot``'s ``out`` keys: the record (None when its tag is not robot
    ``robot``'s: a forgery) and the arrival time (s)."""

    robot: int
    data: bytes | None
    at_s: float


def free_endpoint() -> str:
    """``tcp/127.0.0.1:PORT`` with a port the system has just handed out as free."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def access_rules(run_key: str, num_robots: int) -> dict:
    """Zenoh's ``access_control`` settings of a run: everything denied but, for robot i (user
    ``robotI``), subscribing to and being sent its own ``in`` keys, and publishing on its own ``out``
    keys to the world's subscription."""
    rules, subjects, policies = [], [], []
    for i in range(num_robots):
        mine_in, mine_out = in_key(run_key, i, "*"), out_key(run_key, i, "*")
        rules += [{"id": f"hear{i}", "messages": ["put"], "flows": ["egress"], "permission": "allow", "key_exprs": [mine_in]},
                  {"id": f"listen{i}", "messages": ["declare_subscriber"], "flows": ["ingress"], "permission": "allow",
                   "key_exprs": [mine_in]},
                  {"id": f"speak{i}", "messages": ["put"], "flows": ["ingress"], "permission": "allow", "key_exprs": [mine_out]},
                  {"id": f"heard{i}", "messages": ["declare_subscriber"], "flows": ["egress"], "permission": "allow",
                   "key_exprs": [mine_out]}]
        subjects.append({"id": f"robot{i}", "usernames": [transport_user(i)]})
        policies.append({"rules": [f"hear{i}", f"listen{i}", f"speak{i}", f"heard{i}"], "subjects": [f"robot{i}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


class WorldBus:
    """The world's Zenoh session for ``num_robots`` robots under a fresh run key (:attr:`run_key`),
    listening on :attr:`endpoint`; ``secret``: the run's (default: a fresh one; :meth:`key` gives
    robot i's key)."""

    def __init__(self, num_robots: int, endpoint: str | None = None, run_key: str | None = None,
                 secret: bytes | None = None):
        import zenoh

        self.run_key = run_key or secrets.token_hex(8)
        self.endpoint = endpoint or free_endpoint()
        self.secret = secret or new_secret()
        self.keys = [robot_key(self.secret, i) for i in range(num_robots)]
        self._dir = Path(tempfile.mkdtemp(prefix="madp-swarm-users-"))  # mode 0700: the world's user alone
        users = self._dir / "users"
        users.touch(mode=0o600)
        users.write_text("".join(f"{transport_user(i)}:{transport_password(k)}\n" for i, k in enumerate(self.keys)))
        try:
            self.session = zenoh.open(zenoh_config(listen=self.endpoint, users_file=str(users),
                                                   access=access_rules(self.run_key, num_robots)))
        except BaseException:
            shutil.rmtree(self._dir, ignore_errors=True)
            raise
        self.arrivals: queue.SimpleQueue = queue.SimpleQueue()
        self.subscribers = [self.session.declare_subscriber(out_key(self.run_key, i, "*"), self._arrived)
                            for i in range(num_robots)]
        block = zenoh.CongestionControl.BLOCK
        self.publishers = [{name: self.session.declare_publisher(in_key(self.run_key, i, name), congestion_control=block,
                                                                 express=True) for name in IN_NAMES}
                           for i in range(num_robots)]

    def key(self, robot: int) -> bytes:
        """Robot ``robot``'s key (what it is handed at its start)."""
        return self.keys[robot]

    def _arrived(self, sample) -> None:
        at = time.perf_counter()
        key_expr = str(sample.key_expr)
        robot = robot_of(key_expr)
        if robot is not None and robot < len(self.keys):
            self.arrivals.put(Arrival(robot, unseal(self.keys[robot], key_expr, sample.payload.to_bytes()), at))

    def send(self, robot: int, name: str, data: bytes) -> None:
        self.publishers[robot][name].put(seal(self.keys[robot], in_key(self.run_key, robot, name), data))

    def receive(self, timeout_s: float) -> Arrival | None:
        """The next arrival, or None after ``timeout_s`` seconds without one."""
        try:
            return self.arrivals.get(timeout=max(timeout_s, 0.0))
        except queue.Empty:
            return None

    def close(self) -> None:
        try:
            self.session.close()
        except Exception:  # closing a session whose peers are gone; nothing is left to lose
            pass
        shutil.rmtree(self._dir, ignore_errors=True)
