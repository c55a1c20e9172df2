"""The world's side of the middleware: one Zenoh session listening on a loopback endpoint, one
publisher per robot and ``in`` key, and one subscription to everything the robots send
(:mod:`madp.robot.wire` has the keys and the records).

What arrives is queued with the robot id its key names and the time it arrived
(``time.perf_counter()``, taken in Zenoh's callback); records are decoded by the caller's thread.
"""

from __future__ import annotations

import queue
import secrets
import socket
import time
from dataclasses import dataclass

from madp.robot.wire import in_key, robot_of, world_subscription, zenoh_config

__all__ = ["Arrival", "WorldBus", "free_endpoint", "IN_NAMES"]

#: What the world sends each robot, by key name (``madp/RUN/robot/I/in/NAME``).
IN_NAMES = ("start", "step", "beacons", "tokens", "costs")


@dataclass(frozen=True)
class Arrival:
    """One record a robot sent: ``robot`` (the id its key names), the raw bytes and the arrival time (s)."""

    robot: int
    data: bytes
    at_s: float


def free_endpoint() -> str:
    """``tcp/127.0.0.1:PORT`` with a port the system has just handed out as free."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


class WorldBus:
    """The world's Zenoh session for ``num_robots`` robots under a fresh run key (:attr:`run_key`),
    listening on :attr:`endpoint`."""

    def __init__(self, num_robots: int, endpoint: str | None = None, run_key: str | None = None):
        import zenoh

        self.run_key = run_key or secrets.token_hex(8)
        self.endpoint = endpoint or free_endpoint()
        self.session = zenoh.open(zenoh_config(listen=self.endpoint))
        self.arrivals: queue.SimpleQueue = queue.SimpleQueue()
        self.subscriber = self.session.declare_subscriber(world_subscription(self.run_key), self._arrived)
        block = zenoh.CongestionControl.BLOCK
        self.publishers = [{name: self.session.declare_publisher(in_key(self.run_key, i, name), congestion_control=block,
                                                                 express=True) for name in IN_NAMES}
                           for i in range(num_robots)]

    def _arrived(self, sample) -> None:
        at = time.perf_counter()
        robot = robot_of(str(sample.key_expr))
        if robot is not None:
            self.arrivals.put(Arrival(robot, sample.payload.to_bytes(), at))

    def send(self, robot: int, name: str, data: bytes) -> None:
        self.publishers[robot][name].put(data)

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
