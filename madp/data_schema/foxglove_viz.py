"""Foxglove well-known messages that make an MCAP shard viewable in Foxglove with no plugin.

Everything is drawn in one frame, ``"world"``: x east, y north, z up, metres, origin at the world's
south-west corner (so a robot at X = (x, y) is at (x, y, 0)). Topics:

``/world/map``       ``foxglove.Grid`` — the episode's importance map, once per episode. The 1024²
                     1 m map is block-averaged to at most :data:`GRID_MAX_CELLS` cells per side
                     (256² float32 = 256 KiB, 4 m cells) to keep shards light; the cell size in
                     metres is in the message.
``/robots``          ``foxglove.SceneUpdate`` — one sphere per robot (:data:`ROBOT_DIAMETER_M`).
``/expert/goals``    ``foxglove.SceneUpdate`` — a line from each robot to its expert goal (the
                     Voronoi centroid), when the episode carries goals.
``/expert/actions``  ``foxglove.SceneUpdate`` — a line from each robot along its expert velocity,
                     ``u · ACTION_DRAW_SECONDS`` long (a 5 m/s action draws 25 m).

The messages come from ``foxglove-sdk`` (``foxglove.messages``), whose ``get_schema()`` returns the
published protobuf ``FileDescriptorSet`` and ``encode()`` the protobuf bytes, so they can be written
into an :class:`mcap.writer.Writer` we control (deterministic log times, no wall clock).
"""

from __future__ import annotations

import numpy as np

#: Largest grid side (cells) written to ``/world/map``.
GRID_MAX_CELLS = 256
#: Diameter of a robot's sphere, m.
ROBOT_DIAMETER_M = 10.0
#: Length scale for action lines, s (line = u · this).
ACTION_DRAW_SECONDS = 5.0
#: Thickness of goal/action lines, m.
LINE_THICKNESS_M = 1.5
#: Frame id of every message.
FRAME_ID = "world"

TOPIC_MAP = "/world/map"
TOPIC_ROBOTS = "/robots"
TOPIC_GOALS = "/expert/goals"
TOPIC_ACTIONS = "/expert/actions"


def _fx():
    """Import foxglove.messages lazily (readers never need it)."""
    import foxglove.messages as fx

    return fx


def schemas() -> dict[str, tuple[str, str, bytes]]:
    """Topic → (schema name, schema encoding, schema data) for every visualisation topic."""
    fx = _fx()
    out = {}
    for topic, cls in ((TOPIC_MAP, fx.Grid), (TOPIC_ROBOTS, fx.SceneUpdate), (TOPIC_GOALS, fx.SceneUpdate), (TOPIC_ACTIONS, fx.SceneUpdate)):
        s = cls.get_schema()
        out[topic] = (s.name, s.encoding, bytes(s.data))
    return out


def downsample_map(world_map: np.ndarray, max_cells: int = GRID_MAX_CELLS) -> tuple[np.ndarray, int]:
    """Block-average a ``[Wx, Wy]`` map so neither side exceeds ``max_cells``.

    Returns ``(grid [Wx/f, Wy/f] float32, f)`` where ``f`` is the block size in source cells (the
    largest factor ≤ ``ceil(W / max_cells)`` dividing both sides; 1 keeps the map as is).
    """
    wx, wy = world_map.shape
    f = max(1, -(-max(wx, wy) // max_cells))
    while wx % f or wy % f:
        f -= 1
    if f == 1:
        return np.ascontiguousarray(world_map, dtype=np.float32), 1
    blocks = world_map.astype(np.float64).reshape(wx // f, f, wy // f, f)
    return blocks.mean(axis=(1, 3)).astype(np.float32), f


def _timestamp(log_time_ns: int):
    return _fx().Timestamp(log_time_ns // 1_000_000_000, log_time_ns % 1_000_000_000)


def _identity_pose(z: float = 0.0):
    fx = _fx()
    return fx.Pose(position=fx.Vector3(x=0.0, y=0.0, z=z), orientation=fx.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))


def grid_message(world_map: np.ndarray, log_time_ns: int, cell_m: float = 1.0) -> bytes:
    """Encoded ``foxglove.Grid`` of a ``[Wx, Wy]`` importance map with ``cell_m`` metre cells.

    Foxglove grids are row-major with rows along +y, so the ``[x, y]`` map is written transposed.
    """
    fx = _fx()
    grid, f = downsample_map(world_map)
    cell = float(cell_m * f)
    gx = grid.shape[0]
    return fx.Grid(
        timestamp=_timestamp(log_time_ns),
        frame_id=FRAME_ID,
        pose=_identity_pose(),
        column_count=gx,
        cell_size=fx.Vector2(x=cell, y=cell),
        row_stride=gx * 4,
        cell_stride=4,
        fields=[fx.PackedElementField(name="importance", offset=0, type=fx.PackedElementFieldNumericType.Float32)],
        data=np.ascontiguousarray(grid.T, dtype="<f4").tobytes(),
    ).encode()


def robots_message(positions: np.ndarray, log_time_ns: int) -> bytes:
    """Encoded ``foxglove.SceneUpdate`` with one sphere per robot at ``positions [N, 2]`` (m)."""
    fx = _fx()
    size = fx.Vector3(x=ROBOT_DIAMETER_M, y=ROBOT_DIAMETER_M, z=ROBOT_DIAMETER_M)
    color = fx.Color(r=1.0, g=0.45, b=0.1, a=1.0)
    q = fx.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    spheres = [
        fx.SpherePrimitive(pose=fx.Pose(position=fx.Vector3(x=x, y=y, z=0.0), orientation=q), size=size, color=color)
        for x, y in positions.astype(np.float64).tolist()
    ]
    entity = fx.SceneEntity(timestamp=_timestamp(log_time_ns), frame_id=FRAME_ID, id="robots", spheres=spheres)
    return fx.SceneUpdate(entities=[entity]).encode()


def segments_message(
    starts: np.ndarray, ends: np.ndarray, log_time_ns: int, entity_id: str, rgba: tuple[float, float, float, float]
) -> bytes:
    """Encoded ``foxglove.SceneUpdate`` with one line list: segment i from ``starts[i]`` to ``ends[i]``."""
    fx = _fx()
    return fx.SceneUpdate(entities=[_segments_entity(starts, ends, log_time_ns, entity_id, rgba)]).encode()


#: How :func:`links_message` draws each link state of :mod:`madp.sim.network` (entity id, colour).
LINK_STYLES = {1: ("delivered", (0.2, 0.8, 0.3, 0.8)), 2: ("lost", (0.9, 0.15, 0.15, 0.9)),
               3: ("kept", (0.95, 0.7, 0.1, 0.8))}


def links_message(positions: np.ndarray, links: np.ndarray, log_time_ns: int) -> bytes:
    """Encoded ``foxglove.SceneUpdate`` of the network's links at one step: per state of
    :data:`LINK_STYLES` one entity, a line from sender j to receiver i (``positions [N, 2]``) for every
    link ``links[i, j]`` in that state (an entity with no segments clears the last step's)."""
    fx = _fx()
    p = positions.astype(np.float64)
    entities = []
    for state, (name, rgba) in LINK_STYLES.items():
        i, j = np.nonzero(links == state)
        entities.append(_segments_entity(p[j], p[i], log_time_ns, f"links {name}", rgba))
    return fx.SceneUpdate(entities=entities).encode()


def _segments_entity(starts: np.ndarray, ends: np.ndarray, log_time_ns: int, entity_id: str,
                     rgba: tuple[float, float, float, float]):
    fx = _fx()
    pts = np.empty((2 * len(starts), 2), dtype=np.float64)
    pts[0::2] = starts
    pts[1::2] = ends
    line = fx.LinePrimitive(
        type=fx.LinePrimitiveLineType.LineList,
        pose=_identity_pose(z=1.0),
        thickness=LINE_THICKNESS_M,
        scale_invariant=False,
        points=[fx.Point3(x=x, y=y, z=0.0) for x, y in pts.tolist()],
        color=fx.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
    )
    return fx.SceneEntity(timestamp=_timestamp(log_time_ns), frame_id=FRAME_ID, id=entity_id, lines=[line])


def goals_message(positions: np.ndarray, goals: np.ndarray, log_time_ns: int) -> bytes:
    """Lines from each robot (``positions [N, 2]``) to its expert goal (``goals [N, 2]``), m."""
    return segments_message(positions, goals, log_time_ns, "goals", (0.1, 0.8, 0.2, 1.0))


def actions_message(positions: np.ndarray, actions: np.ndarray, log_time_ns: int) -> bytes:
    """Lines from each robot along its velocity ``actions [N, 2]`` (m/s) × ACTION_DRAW_SECONDS."""
    p = positions.astype(np.float64)
    return segments_message(p, p + ACTION_DRAW_SECONDS * actions.astype(np.float64), log_time_ns, "actions", (0.2, 0.4, 1.0, 1.0))


__all__ = [
    "ACTION_DRAW_SECONDS",
    "FRAME_ID",
    "GRID_MAX_CELLS",
    "LINK_STYLES",
    "ROBOT_DIAMETER_M",
    "TOPIC_ACTIONS",
    "TOPIC_GOALS",
    "TOPIC_MAP",
    "TOPIC_ROBOTS",
    "actions_message",
    "downsample_map",
    "goals_message",
    "grid_message",
    "links_message",
    "robots_message",
    "schemas",
]
