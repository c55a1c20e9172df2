"""One evaluation rollout as an MCAP file a person opens in Foxglove and watches.

:func:`write_rollout_mcap` writes the world map, the robots, their Voronoi cells, their paths, their
velocity commands and (for MADP) the fans of sampled actions, all as ``foxglove-sdk`` well-known
messages (``foxglove.Grid``, ``foxglove.SceneUpdate``), so Foxglove shows them with no plugin.

Conventions are those of :mod:`madp.data_schema.foxglove_viz`: one frame ``"world"``, x east, y north,
z up, metres, origin at the world's south-west corner; maps are indexed ``[x, y]`` with 1 m cells.

Topics (``S`` = recorded steps: every ``every``-th step of ``0..T`` plus the last step ``T``):

``/world/map``     ``foxglove.Grid``, once at t = 0: the importance map, block-averaged to at most
                   256² cells (:func:`madp.data_schema.foxglove_viz.grid_message`).
``/robots``        ``foxglove.SceneUpdate``, at every step of S: per robot an entity ``robot {i}``
                   holding a sphere (:data:`~madp.data_schema.foxglove_viz.ROBOT_DIAMETER_M`) and a
                   billboard label with the index ``i``, both in the robot's colour.
``/voronoi``       ``foxglove.SceneUpdate``, at every step of S: per robot an entity ``robot {i}``
                   with one closed ``LineLoop`` — its Voronoi cell among all robots, clipped to the
                   world rectangle ``[0, Wx] × [0, Wy]``, vertices counter-clockwise. A robot sharing
                   its exact position with a lower-indexed robot owns no cell (the simulator's
                   nearest-robot rule breaks ties by index) and its entity has no lines.
``/trajectories``  ``foxglove.SceneUpdate``, at every step of S: per robot an entity ``robot {i}`` with
                   a ``LineStrip`` of its path from step 0 to the current step, thinned to at most
                   :data:`TRAJECTORY_MAX_POINTS` points (a fixed stride, always ending at the current
                   position).
``/actions``       ``foxglove.SceneUpdate``, at every step of S: one line per robot along its commanded
                   velocity, ``u · 5 s`` long (:func:`madp.data_schema.foxglove_viz.actions_message`).
                   At step T there is no command; that message deletes the lines.
``/samples``       only when ``samples_mps`` is given; ``foxglove.SceneUpdate`` at every step of S: per
                   robot an entity ``robot {i}`` with one thin, semi-transparent ``LineStrip`` per
                   sampled action — the finite-horizon trajectory of holding that velocity for
                   ``sample_horizon_steps`` steps of ``dt_s`` (``sample_horizon_steps + 1`` points,
                   clamped to the world like the simulator's positions), the "fan of possible futures"
                   of the paper's Figure 1. NaN samples are skipped. At step T the fans are deleted.
``/network/links`` only when ``links`` is given (a rollout over a network); ``foxglove.SceneUpdate`` at
                   every step of S: a line from sender to receiver for every link, green where the
                   message was delivered, red where it was lost, amber where an older message was kept
                   (:func:`madp.data_schema.foxglove_viz.links_message`).

Every robot has one stable colour (:func:`robot_colors`, golden-ratio steps around the HSV hue
wheel, independent of N) shared by its sphere, label, cell outline, path and samples. Within every
per-step SceneUpdate except ``/actions`` the entities are in robot order, one per robot, always all N
(an entity with no primitives clears what the robot showed before).

A metadata record :data:`METADATA_NAME` carries the controller, title, N, T, dt and the recording
parameters. Log (and publish) times are simulated time, step t at ``t · dt_s`` (integer ns), never
wall clock; with fixed zstd chunking the file's bytes are a pure function of the input. The file is
written to ``path.<pid>.tmp`` and renamed into place (:func:`madp.io.atomic.atomic_path`).

In Foxglove: open the file, add a **3D** panel, set its display frame to ``world`` and (for a map
view) switch the camera to 2D / top-down; enable the topics in the panel's settings. The grid's
colour mode can be set to a colour map of the ``importance`` field (0..1).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional, Union

import numpy as np

from madp.data_schema.foxglove_viz import (
    FRAME_ID,
    ROBOT_DIAMETER_M,
    TOPIC_MAP,
    TOPIC_ROBOTS,
    _identity_pose,
    _timestamp,
    actions_message,
    grid_message,
    links_message,
)
from madp.io.atomic import atomic_path
from madp.render import robot_colors

PathLike = Union[str, os.PathLike]

TOPIC_VORONOI = "/voronoi"
TOPIC_TRAJECTORIES = "/trajectories"
TOPIC_ROLLOUT_ACTIONS = "/actions"
TOPIC_SAMPLES = "/samples"
TOPIC_LINKS = "/network/links"
#: Name of the file's metadata record.
METADATA_NAME = "madp.rollout"
#: Most points drawn per robot path.
TRAJECTORY_MAX_POINTS = 200
#: Line thicknesses, screen pixels (scale-invariant, so they stay visible when zoomed out).
VORONOI_THICKNESS_PX = 2.0
TRAJECTORY_THICKNESS_PX = 2.5
SAMPLE_THICKNESS_PX = 1.5
#: Opacity of sampled-trajectory lines and of cell outlines.
SAMPLE_ALPHA = 0.45
VORONOI_ALPHA = 0.9
#: Heights (z, m) of the layers: outlines and paths just above the grid, fans above the spheres.
VORONOI_Z = 0.5
TRAJECTORY_Z = 1.0
SAMPLE_Z = 0.5 * ROBOT_DIAMETER_M + 1.0
LABEL_Z = ROBOT_DIAMETER_M + 2.0
LABEL_FONT_PX = 14.0
#: Path and sample points are rounded to multiples of this (m, a binary fraction: 3.9 mm, far below
#: what a screen shows) so their float64 coordinates compress about 2.3x better under zstd.
DRAW_QUANTUM_M = 1.0 / 256.0
#: Uncompressed MCAP chunk size target, bytes.
CHUNK_BYTES = 1 << 20

# --------------------------------------------------------------------------------------------
# geometry and colours


def _clip_halfplanes(poly: np.ndarray, count: np.ndarray, normal: np.ndarray, point: np.ndarray, empty: np.ndarray):
    """Clip R convex polygons by one half-plane each (Sutherland–Hodgman, vectorised over R).

    ``poly [R, K, 2]`` holds ``count [R]`` vertices each; the half-plane of row r keeps the points q
    with ``normal[r] · (q − point[r]) <= 0`` (``normal = 0`` keeps everything); rows with ``empty``
    lose all vertices. Returns the clipped ``(poly [R, K', 2], count [R])``; vertex order is kept.
    """
    r, k = poly.shape[:2]
    slot = np.arange(k)
    valid = slot[None, :] < count[:, None]
    s = np.einsum("rkd,rd->rk", poly - point[:, None, :], normal)
    s[empty] = 1.0
    inside = s <= 0.0
    nxt = np.where(slot[None, :] + 1 < count[:, None], slot[None, :] + 1, 0)
    s_next = np.take_along_axis(s, nxt, 1)
    p_next = np.take_along_axis(poly, nxt[..., None], 1)
    cross = valid & (inside != (s_next <= 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(cross, s / (s - s_next), 0.0)
    crossing = poly + t[..., None] * (p_next - poly)
    out = np.stack([poly, crossing], axis=2).reshape(r, 2 * k, 2)
    keep = np.stack([valid & inside, cross], axis=2).reshape(r, 2 * k)
    new_count = keep.sum(1)
    order = np.argsort(~keep, axis=1, kind="stable")[:, : max(int(new_count.max(initial=0)), 1)]
    return np.take_along_axis(out, order[..., None], 1), new_count


def voronoi_cells(sites_m: np.ndarray, size_m: tuple[float, float]) -> list[np.ndarray]:
    """Voronoi cells of ``sites_m [N, 2]`` clipped to the rectangle ``[0, size_x] × [0, size_y]``.

    Each cell is the box clipped by the bisector half-planes of the other sites, nearest first,
    vectorised over robots; a robot stops being clipped once its next competitor is farther than
    twice its cell's radius (no farther bisector can reach the cell). Works for any N ≥ 1, collinear
    sites included. A site at exactly the position of a lower-indexed site gets an empty cell (ties go
    to the lower index, as in the simulator's rasterisation), so the cells always tile the box.

    Returns N arrays ``[K_i, 2]`` (m) of counter-clockwise vertices without repeating the first one;
    ``[0, 2]`` for an empty cell.
    """
    sites = np.asarray(sites_m, dtype=np.float64)
    n = len(sites)
    sx, sy = float(size_m[0]), float(size_m[1])
    box = np.array([[0.0, 0.0], [sx, 0.0], [sx, sy], [0.0, sy]])
    poly = np.broadcast_to(box, (n, 4, 2)).copy()
    count = np.full(n, 4)
    if n > 1:
        dist = np.linalg.norm(sites[:, None, :] - sites[None, :, :], axis=-1)
        np.fill_diagonal(dist, -1.0)  # self first, even among duplicates
        rank = np.argsort(dist, axis=1, kind="stable")[:, 1:]  # [N, N-1] competitors, nearest first
        rows = np.arange(n)
        for col in range(n - 1):
            j = rank[:, col]
            d = sites[j] - sites
            dd = dist[rows, j]
            slot_ok = np.arange(poly.shape[1])[None, :] < count[:, None]
            radius = np.where(slot_ok, np.linalg.norm(poly - sites[:, None, :], axis=-1), 0.0).max(1)
            active = (count > 0) & (dd <= 2.0 * radius * (1 + 1e-12) + 1e-12)
            if not active.any():
                break
            dup = active & (dd == 0.0)
            normal = np.where((active & ~dup)[:, None], d, 0.0)
            poly, count = _clip_halfplanes(poly, count, normal, 0.5 * (sites + sites[j]), dup & (j < rows))
    cells = []
    tol = 1e-9 * max(sx, sy, 1.0)
    for i in range(n):
        c = poly[i, : count[i]]
        if len(c):  # drop repeated vertices (a clip line through a vertex yields it twice)
            keep = np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1) > tol
            c = c[keep] if keep.any() else c[:1]
        cells.append(c)
    return cells


def _trajectory_indices(step: int, max_points: int = TRAJECTORY_MAX_POINTS) -> np.ndarray:
    """Steps drawn for the path up to ``step``: a fixed stride from 0, always ending at ``step``."""
    stride = max(1, -(-step // max(max_points - 1, 1)))
    idx = np.arange(0, step + 1, stride)
    return idx if idx[-1] == step else np.append(idx, step)


# --------------------------------------------------------------------------------------------
# messages


def _color(rgb, alpha: float = 1.0):
    import foxglove.messages as fx

    return fx.Color(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=float(alpha))


def _points(xy: np.ndarray):
    import foxglove.messages as fx

    return [fx.Point3(x=x, y=y, z=0.0) for x, y in np.asarray(xy, dtype=np.float64).tolist()]


def _quantize(xy: np.ndarray) -> np.ndarray:
    """Round drawn coordinates to :data:`DRAW_QUANTUM_M` (exactly representable, deterministic)."""
    return np.round(np.asarray(xy, dtype=np.float64) / DRAW_QUANTUM_M) * DRAW_QUANTUM_M


def _line(kind, xy: np.ndarray, z: float, thickness_px: float, color):
    import foxglove.messages as fx

    return fx.LinePrimitive(
        type=kind, pose=_identity_pose(z=z), thickness=thickness_px, scale_invariant=True, points=_points(xy), color=color
    )


def _entity(log_time_ns: int, i: int, **primitives):
    import foxglove.messages as fx

    return fx.SceneEntity(timestamp=_timestamp(log_time_ns), frame_id=FRAME_ID, id=f"robot {i}", **primitives)


def _scene(entities) -> bytes:
    import foxglove.messages as fx

    return fx.SceneUpdate(entities=list(entities)).encode()


def _delete_all(log_time_ns: int) -> bytes:
    """A SceneUpdate deleting every entity of its topic published before ``log_time_ns``."""
    import foxglove.messages as fx

    deletion = fx.SceneEntityDeletion(timestamp=_timestamp(log_time_ns), type=fx.SceneEntityDeletionType.All)
    return fx.SceneUpdate(deletions=[deletion]).encode()


def robots_scene(positions: np.ndarray, colors: np.ndarray, log_time_ns: int) -> bytes:
    """Per robot a sphere in its colour and a billboard label with its index."""
    import foxglove.messages as fx

    size = fx.Vector3(x=ROBOT_DIAMETER_M, y=ROBOT_DIAMETER_M, z=ROBOT_DIAMETER_M)
    q = fx.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    out = []
    for i, (x, y) in enumerate(np.asarray(positions, dtype=np.float64).tolist()):
        color = _color(colors[i])
        sphere = fx.SpherePrimitive(pose=fx.Pose(position=fx.Vector3(x=x, y=y, z=0.0), orientation=q), size=size, color=color)
        label = fx.TextPrimitive(
            pose=fx.Pose(position=fx.Vector3(x=x, y=y, z=LABEL_Z), orientation=q),
            billboard=True, font_size=LABEL_FONT_PX, scale_invariant=True, color=color, text=str(i),
        )
        out.append(_entity(log_time_ns, i, spheres=[sphere], texts=[label]))
    return _scene(out)


def voronoi_scene(positions: np.ndarray, size_m: tuple[float, float], colors: np.ndarray, log_time_ns: int) -> bytes:
    """Per robot one closed outline of its Voronoi cell clipped to the world (none if empty)."""
    import foxglove.messages as fx

    cells = voronoi_cells(positions, size_m)
    return _scene(
        _entity(
            log_time_ns, i,
            lines=[_line(fx.LinePrimitiveLineType.LineLoop, c, VORONOI_Z, VORONOI_THICKNESS_PX, _color(colors[i], VORONOI_ALPHA))]
            if len(c) else [],
        )
        for i, c in enumerate(cells)
    )


def trajectories_scene(paths: np.ndarray, colors: np.ndarray, log_time_ns: int) -> bytes:
    """Per robot one line strip through ``paths [N, P, 2]`` (rounded to :data:`DRAW_QUANTUM_M`)."""
    import foxglove.messages as fx

    paths = _quantize(paths)
    kind = fx.LinePrimitiveLineType.LineStrip
    return _scene(
        _entity(log_time_ns, i, lines=[_line(kind, p, TRAJECTORY_Z, TRAJECTORY_THICKNESS_PX, _color(colors[i]))])
        for i, p in enumerate(paths)
    )


def sample_paths(positions: np.ndarray, samples: np.ndarray, dt_s: float, horizon_steps: int, size_m: tuple[float, float]) -> np.ndarray:
    """Finite-horizon paths ``[N, M, H+1, 2]`` of holding each sampled velocity ``samples [N, M, 2]``.

    Point k is ``x + k·dt·u`` clamped per coordinate to the world, which is exactly where the
    simulator's clamped single integrator would be after k steps of the constant velocity.
    """
    k = np.arange(horizon_steps + 1, dtype=np.float64)[:, None] * dt_s
    pts = positions[:, None, None, :] + k[None, None] * samples[:, :, None, :]
    return np.clip(pts, 0.0, np.asarray(size_m, dtype=np.float64))


def samples_scene(paths: np.ndarray, colors: np.ndarray, log_time_ns: int) -> bytes:
    """Per robot one thin translucent line strip per finite sampled path of ``paths [N, M, H+1, 2]``
    (rounded to :data:`DRAW_QUANTUM_M`)."""
    import foxglove.messages as fx

    paths = _quantize(paths)
    kind = fx.LinePrimitiveLineType.LineStrip
    finite = np.isfinite(paths).all(axis=(2, 3))
    return _scene(
        _entity(
            log_time_ns, i,
            lines=[_line(kind, paths[i, m], SAMPLE_Z, SAMPLE_THICKNESS_PX, _color(colors[i], SAMPLE_ALPHA))
                   for m in np.flatnonzero(finite[i])],
        )
        for i in range(len(paths))
    )


# --------------------------------------------------------------------------------------------
# the file


def recorded_steps(num_steps: int, every: int) -> np.ndarray:
    """Steps written for a rollout of ``num_steps`` steps (positions 0..T): every ``every``-th and T."""
    steps = np.arange(0, num_steps + 1, every)
    return steps if steps[-1] == num_steps else np.append(steps, num_steps)


def write_rollout_mcap(
    path: PathLike,
    world_map: np.ndarray,
    positions_m: np.ndarray,
    actions_mps: np.ndarray,
    controller: str,
    dt_s: float = 0.2,
    samples_mps: Optional[np.ndarray] = None,
    sample_horizon_steps: int = 10,
    every: int = 1,
    title: str = "",
    extra_metadata: Optional[dict] = None,
    links: Optional[np.ndarray] = None,
) -> dict:
    """Write one evaluation rollout as a Foxglove-viewable MCAP file (see the module docstring).

    Args:
        path: output file; written as ``path.<pid>.tmp`` and renamed into place.
        world_map: ``[Wx, Wy]`` importance map, indexed ``[x, y]``, 1 m cells (the world is
            ``[0, Wx] × [0, Wy]`` m).
        positions_m: ``[T+1, N, 2]`` robot positions at steps 0..T, m.
        actions_mps: ``[T, N, 2]`` commanded velocities at steps 0..T−1, m/s (NaN rows are not drawn).
        controller: controller name (e.g. ``"madp"``, ``"lpac"``, ``"cvt"``), stored in the metadata.
        dt_s: simulated seconds per step; step t is logged at ``t · dt_s``.
        samples_mps: optional ``[T, N, M, 2]`` sampled velocities per robot and step (NaN where not
            sampled), drawn as fans on ``/samples``.
        sample_horizon_steps: steps each sampled velocity is held for its drawn path.
        every: record every ``every``-th step (and always the last, T).
        title: free text stored in the metadata (e.g. scenario and seed).
        extra_metadata: more ``{key: value}`` for the metadata record (MADP: its
            :class:`madp.policies.SamplingSettings`, ``sampler``, ``sampling_steps``, ``eta``, …,
            ``select``, ``candidates``).
        links: optional ``[T+1, N, N]`` int8, the network's links at steps 0..T (``madp.sim.rollout.Links``).

    Returns:
        ``{"path": str, "bytes": file size, "messages": total messages, "topics": {topic: count}}``.

    Raises:
        ValueError: on inconsistent shapes, non-finite positions or non-positive parameters.
    """
    import foxglove.messages as fx
    from mcap.well_known import MessageEncoding

    from madp.data_schema.mcap_codec import start_writer

    world = np.asarray(world_map)
    pos = np.asarray(positions_m, dtype=np.float64)
    act = np.asarray(actions_mps, dtype=np.float64)
    if world.ndim != 2 or min(world.shape) < 1:
        raise ValueError(f"world_map must be a non-empty [Wx, Wy] array, got shape {world.shape}")
    if pos.ndim != 3 or pos.shape[2] != 2 or pos.shape[0] < 1 or pos.shape[1] < 1:
        raise ValueError(f"positions_m must be [T+1, N, 2] with T >= 0, N >= 1, got shape {pos.shape}")
    num_steps, n = pos.shape[0] - 1, pos.shape[1]
    if act.shape != (num_steps, n, 2):
        raise ValueError(f"actions_mps must be [T, N, 2] = {(num_steps, n, 2)}, got shape {act.shape}")
    if not np.isfinite(pos).all():
        raise ValueError("positions_m must be finite")
    samples = None
    if samples_mps is not None:
        samples = np.asarray(samples_mps, dtype=np.float64)
        if samples.ndim != 4 or samples.shape[:2] != (num_steps, n) or samples.shape[3] != 2:
            raise ValueError(f"samples_mps must be [T, N, M, 2] with T, N = {num_steps}, {n}, got shape {samples.shape}")
    if int(every) < 1 or int(sample_horizon_steps) < 1:
        raise ValueError(f"every and sample_horizon_steps must be >= 1, got {every} and {sample_horizon_steps}")
    step_ns = int(round(float(dt_s) * 1e9))
    if step_ns <= 0:
        raise ValueError(f"dt_s must be positive, got {dt_s}")

    size_m = (float(world.shape[0]), float(world.shape[1]))
    colors = robot_colors(n)
    steps = recorded_steps(num_steps, int(every))
    scene_topics = [TOPIC_ROBOTS, TOPIC_VORONOI, TOPIC_TRAJECTORIES, TOPIC_ROLLOUT_ACTIONS]
    if samples is not None:
        scene_topics.append(TOPIC_SAMPLES)
    if links is not None:
        scene_topics.append(TOPIC_LINKS)

    final = Path(os.fspath(path))
    counts: dict[str, int] = {}
    with atomic_path(final) as tmp, open(tmp, "wb") as f:
        writer = start_writer(f, CHUNK_BYTES)
        channels: dict[str, int] = {}
        schema_ids: dict[str, int] = {}
        for topic, cls in [(TOPIC_MAP, fx.Grid)] + [(t, fx.SceneUpdate) for t in scene_topics]:
            schema = cls.get_schema()
            if schema.name not in schema_ids:
                schema_ids[schema.name] = writer.register_schema(name=schema.name, encoding=schema.encoding, data=bytes(schema.data))
            channels[topic] = writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=schema_ids[schema.name]
            )
            counts[topic] = 0

        def emit(topic: str, log_time: int, data: bytes) -> None:
            writer.add_message(
                channel_id=channels[topic], log_time=log_time, data=data, publish_time=log_time, sequence=counts[topic]
            )
            counts[topic] += 1

        emit(TOPIC_MAP, 0, grid_message(world, 0))
        for t in steps.tolist():
            log_time = t * step_ns
            p = pos[t]
            emit(TOPIC_ROBOTS, log_time, robots_scene(p, colors, log_time))
            emit(TOPIC_VORONOI, log_time, voronoi_scene(p, size_m, colors, log_time))
            emit(TOPIC_TRAJECTORIES, log_time, trajectories_scene(pos[_trajectory_indices(t)].transpose(1, 0, 2), colors, log_time))
            if t < num_steps:
                ok = np.isfinite(act[t]).all(axis=1)
                emit(TOPIC_ROLLOUT_ACTIONS, log_time, actions_message(p[ok], act[t][ok], log_time))
            else:
                emit(TOPIC_ROLLOUT_ACTIONS, log_time, _delete_all(log_time))
            if samples is not None:
                if t < num_steps:
                    fans = sample_paths(p, samples[t], float(dt_s), int(sample_horizon_steps), size_m)
                    emit(TOPIC_SAMPLES, log_time, samples_scene(fans, colors, log_time))
                else:
                    emit(TOPIC_SAMPLES, log_time, _delete_all(log_time))
            if links is not None:
                emit(TOPIC_LINKS, log_time, links_message(p, links[t], log_time))

        from madp import __version__

        writer.add_metadata(
            METADATA_NAME,
            {
                "controller": str(controller),
                "title": str(title),
                "num_robots": str(n),
                "num_steps": str(num_steps),
                "step_seconds": repr(float(dt_s)),
                "every": str(int(every)),
                "recorded_steps": str(len(steps)),
                "samples_per_robot": str(samples.shape[2]) if samples is not None else "0",
                "sample_horizon_steps": str(int(sample_horizon_steps)),
                "world_size_m": f"{size_m[0]:g}x{size_m[1]:g}",
                "frame_id": FRAME_ID,
                "code_version": __version__,
                **{str(k): str(v) for k, v in (extra_metadata or {}).items()},
            },
        )
        writer.finish()
    return {"path": str(final), "bytes": final.stat().st_size, "messages": sum(counts.values()), "topics": counts}


__all__ = [
    "METADATA_NAME",
    "TOPIC_LINKS",
    "TOPIC_ROLLOUT_ACTIONS",
    "TOPIC_SAMPLES",
    "TOPIC_TRAJECTORIES",
    "TOPIC_VORONOI",
    "recorded_steps",
    "robot_colors",
    "sample_paths",
    "voronoi_cells",
    "write_rollout_mcap",
]
