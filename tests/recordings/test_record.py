"""Tests of the rollout recorder (``madp.recordings.record``): topics, counts, geometry, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from madp.recordings.record import (
    METADATA_NAME,
    recorded_steps,
    robot_colors,
    voronoi_cells,
    write_rollout_mcap,
)

W, T, N, M, DT = 256, 20, 5, 3, 0.2
EVERY = 3
STEPS = [0, 3, 6, 9, 12, 15, 18, 20]
SCENE_TOPICS = ["/robots", "/voronoi", "/trajectories", "/actions", "/samples"]


def _rollout(seed: int = 0, n: int = N, t: int = T, m: int = M):
    """A random walk in a W² world with a bumpy map, commands and sampled actions (some NaN)."""
    rng = np.random.default_rng(seed)
    xs = np.arange(W) + 0.5
    world = np.exp(-((xs[:, None] - 80.0) ** 2 + (xs[None, :] - 170.0) ** 2) / (2 * 30.0**2))
    actions = rng.uniform(-5, 5, (t, n, 2))
    pos = np.empty((t + 1, n, 2))
    pos[0] = rng.uniform(20, W - 20, (n, 2))
    for k in range(t):
        pos[k + 1] = np.clip(pos[k] + DT * actions[k], 1e-4, W - 1e-4)
    samples = actions[:, :, None, :] + rng.normal(0, 1.5, (t, n, m, 2))
    samples[1::2, 0, -1] = np.nan  # robot 0 has one sample fewer at odd steps
    return world, pos, actions, samples


def _read(path):
    """(summary, metadata {name: dict}, messages [(topic, schema name, log_time, decoded)])."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        meta = {r.name: dict(r.metadata) for r in reader.iter_metadata()}
        msgs = [(c.topic, s.name, m.log_time, d) for s, c, m, d in reader.iter_decoded_messages()]
    return summary, meta, msgs


def _area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _inside_convex(poly: np.ndarray, q: np.ndarray, tol: float = 1e-9) -> bool:
    """q inside (or on) the counter-clockwise convex polygon."""
    e = np.roll(poly, -1, axis=0) - poly
    r = q - poly
    return bool(np.all(e[:, 0] * r[:, 1] - e[:, 1] * r[:, 0] >= -tol))


def _xy(points) -> np.ndarray:
    return np.array([[p.x, p.y] for p in points], dtype=np.float64).reshape(-1, 2)


def _line_type(line) -> str:
    return line.DESCRIPTOR.fields_by_name["type"].enum_type.values_by_number[line.type].name


def _rgba(c) -> tuple:
    return (round(c.r, 6), round(c.g, 6), round(c.b, 6))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    world, pos, actions, samples = _rollout()
    path = tmp_path_factory.mktemp("rec") / "rollout.mcap"
    info = write_rollout_mcap(
        path, world, pos, actions, "madp", dt_s=DT, samples_mps=samples, sample_horizon_steps=10, every=EVERY, title="unit test"
    )
    return path, info, (world, pos, actions, samples), _read(path)


def test_topics_schemas_and_counts(recorded):
    path, info, _, (summary, _, msgs) = recorded
    schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert schemas == {"/world/map": "foxglove.Grid", **{t: "foxglove.SceneUpdate" for t in SCENE_TOPICS}}
    assert all(c.message_encoding == "protobuf" for c in summary.channels.values())
    counts = {c.topic: summary.statistics.channel_message_counts[c.id] for c in summary.channels.values()}
    assert counts == {"/world/map": 1, **{t: len(STEPS) for t in SCENE_TOPICS}}
    assert info["topics"] == counts and info["messages"] == len(msgs) == 1 + 5 * len(STEPS)
    assert info["bytes"] == path.stat().st_size and info["path"] == str(path)
    assert not path.with_name(path.name + ".tmp").exists()
    assert recorded_steps(T, EVERY).tolist() == STEPS
    # log times are simulated time; every decoded message is one of the recorded steps
    for topic in SCENE_TOPICS:
        times = [lt for tp, _, lt, _ in msgs if tp == topic]
        assert times == [round(s * DT * 1e9) for s in STEPS]
    grid = next(d for tp, _, _, d in msgs if tp == "/world/map")
    assert grid.frame_id == "world" and grid.column_count == W and grid.cell_size.x == pytest.approx(1.0)


def test_metadata_record(recorded):
    _, _, _, (_, meta, _) = recorded
    md = meta[METADATA_NAME]
    assert md["controller"] == "madp" and md["title"] == "unit test"
    assert (md["num_robots"], md["num_steps"], float(md["step_seconds"])) == (str(N), str(T), DT)
    assert md["every"] == str(EVERY) and md["recorded_steps"] == str(len(STEPS)) and md["samples_per_robot"] == str(M)


def _scene_at(msgs, topic, step):
    return next(d for tp, _, lt, d in msgs if tp == topic and lt == round(step * DT * 1e9))


def test_voronoi_cells_tile_the_world(recorded):
    _, _, (_, pos, _, _), (_, _, msgs) = recorded
    for step in (0, 9, 20):
        scene = _scene_at(msgs, "/voronoi", step)
        assert [e.id for e in scene.entities] == [f"robot {i}" for i in range(N)]
        assert all(e.frame_id == "world" for e in scene.entities)
        polys = []
        for e in scene.entities:
            assert len(e.lines) == 1 and _line_type(e.lines[0]) == "LINE_LOOP"
            polys.append(_xy(e.lines[0].points))
        assert sum(_area(p) for p in polys) == pytest.approx(W * W, rel=1e-9)
        for i, p in enumerate(polys):
            assert _area(p) > 0  # counter-clockwise, non-degenerate
            assert p.min() >= -1e-9 and p.max() <= W + 1e-9
            assert _inside_convex(p, pos[step, i])


def test_robots_trajectories_samples_share_colours(recorded):
    _, _, (_, pos, actions, samples), (_, _, msgs) = recorded
    step = 9
    robots = _scene_at(msgs, "/robots", step)
    colors = robot_colors(N)
    for i, e in enumerate(robots.entities):
        s = e.spheres[0]
        assert (s.pose.position.x, s.pose.position.y) == pytest.approx(tuple(pos[step, i]))
        assert e.texts[0].text == str(i)
        assert np.allclose([s.color.r, s.color.g, s.color.b], colors[i])
    others = {t: _scene_at(msgs, t, step) for t in ("/voronoi", "/trajectories", "/samples")}
    for i in range(N):
        ref = _rgba(robots.entities[i].spheres[0].color)
        for scene in others.values():
            assert all(_rgba(line.color) == ref for line in scene.entities[i].lines)
    assert len({_rgba(e.spheres[0].color) for e in robots.entities}) == N

    # the path from step 0 to the current step
    traj = others["/trajectories"]
    for i, e in enumerate(traj.entities):
        assert _line_type(e.lines[0]) == "LINE_STRIP"
        pts = _xy(e.lines[0].points)
        assert len(pts) == step + 1
        assert np.allclose(pts, pos[: step + 1, i], atol=1 / 256)

    # fans: one line of H+1 points per finite sample, holding the sampled velocity
    fans = others["/samples"]
    for i, e in enumerate(fans.entities):
        finite = np.flatnonzero(np.isfinite(samples[step, i]).all(1))
        assert len(e.lines) == len(finite) == (M - 1 if i == 0 else M)
        for line, m in zip(e.lines, finite):
            pts = _xy(line.points)
            assert len(pts) == 11 and 0 < line.color.a < 1
            want = np.clip(pos[step, i] + np.arange(11)[:, None] * DT * samples[step, i, m], 0, W)
            assert np.allclose(pts, want, atol=1 / 256)

    # commanded velocity lines, u · 5 s long
    act = _scene_at(msgs, "/actions", step).entities[0].lines[0]
    pts = _xy(act.points)
    assert np.allclose(pts[0::2], pos[step]) and np.allclose(pts[1::2], pos[step] + 5.0 * actions[step])


def test_last_step_clears_commands_and_fans(recorded):
    _, _, _, (_, _, msgs) = recorded
    for topic in ("/actions", "/samples"):
        last = _scene_at(msgs, topic, T)
        assert len(last.entities) == 0 and len(last.deletions) == 1


def test_byte_identical_output(tmp_path):
    world, pos, actions, samples = _rollout(seed=3, t=6)
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    write_rollout_mcap(a, world, pos, actions, "madp", samples_mps=samples, every=2, title="x")
    write_rollout_mcap(str(b), world.copy(), pos.copy(), actions.copy(), "madp", samples_mps=samples.copy(), every=2, title="x")
    assert a.read_bytes() == b.read_bytes()


def test_single_robot_and_no_samples(tmp_path):
    world, pos, actions, _ = _rollout(seed=4, n=1, t=4)
    info = write_rollout_mcap(tmp_path / "one.mcap", world, pos, actions, "cvt")
    assert info["topics"] == {"/world/map": 1, "/robots": 5, "/voronoi": 5, "/trajectories": 5, "/actions": 5}
    _, meta, msgs = _read(tmp_path / "one.mcap")
    assert meta[METADATA_NAME]["samples_per_robot"] == "0"
    cell = _xy(_scene_at(msgs, "/voronoi", 4).entities[0].lines[0].points)
    assert _area(cell) == pytest.approx(W * W)


def test_collinear_and_duplicate_positions(tmp_path):
    line = np.stack([np.linspace(10.0, 240.0, 6), np.full(6, 100.0)], 1)
    diag = np.stack([np.linspace(10.0, 240.0, 6)] * 2, 1)
    dup = np.array([[50.0, 50.0], [50.0, 50.0], [200.0, 30.0], [50.0, 50.0]])
    for sites in (line, diag, dup):
        cells = voronoi_cells(sites, (W, W))
        assert sum(_area(c) for c in cells if len(c)) == pytest.approx(W * W, rel=1e-9)
        owned = [i for i, c in enumerate(cells) if len(c)]
        for i in owned:
            assert _inside_convex(cells[i], sites[i])
    assert [len(c) > 0 for c in voronoi_cells(dup, (W, W))] == [True, False, True, False]

    pos = np.broadcast_to(diag, (3, 6, 2)).copy()
    info = write_rollout_mcap(tmp_path / "diag.mcap", np.ones((W, W)), pos, np.zeros((2, 6, 2)), "cvt")
    assert info["topics"]["/voronoi"] == 3
    pos = np.broadcast_to(dup, (2, 4, 2)).copy()
    write_rollout_mcap(tmp_path / "dup.mcap", np.ones((W, W)), pos, np.zeros((1, 4, 2)), "cvt")
    scene = _scene_at(_read(tmp_path / "dup.mcap")[2], "/voronoi", 1)
    assert [len(e.lines) for e in scene.entities] == [1, 0, 1, 0]


def test_voronoi_cells_match_nearest_site():
    """Random query points lie in the cell of their nearest site (brute force)."""
    rng = np.random.default_rng(7)
    sites = rng.uniform(0, 300, (40, 2))
    cells = voronoi_cells(sites, (300.0, 200.0))  # sites beyond y = 200 may own no cell
    q = rng.uniform([0, 0], [300, 200], (400, 2))
    nearest = np.argmin(np.linalg.norm(q[:, None] - sites[None], axis=-1), axis=1)
    for k in range(len(q)):
        assert _inside_convex(cells[nearest[k]], q[k], tol=1e-6)
    assert sum(_area(c) for c in cells if len(c)) == pytest.approx(300.0 * 200.0, rel=1e-9)


def test_robot_colors_stable_and_distinct():
    c5, c32 = robot_colors(5), robot_colors(32)
    assert np.array_equal(c5, c32[:5])
    assert c32.min() >= 0 and c32.max() <= 1
    assert len(np.unique(np.round(c32, 4), axis=0)) == 32


def test_rejects_bad_input(tmp_path):
    world, pos, actions, samples = _rollout(t=4)
    bad = [
        dict(actions_mps=actions[:-1]),
        dict(samples_mps=samples[:, :, :, :1]),
        dict(every=0),
        dict(dt_s=0.0),
        dict(positions_m=np.where(np.arange(5)[:, None, None] == 2, np.nan, pos)),
    ]
    for kw in bad:
        args = dict(world_map=world, positions_m=pos, actions_mps=actions, controller="madp")
        args.update(kw)
        with pytest.raises(ValueError):
            write_rollout_mcap(tmp_path / "bad.mcap", **args)
    assert not list(tmp_path.iterdir())


def test_long_paths_are_thinned(tmp_path):
    world, pos, actions, _ = _rollout(seed=5, n=2, t=450)
    write_rollout_mcap(tmp_path / "long.mcap", world, pos, actions, "lpac", every=225)
    msgs = _read(tmp_path / "long.mcap")[2]
    assert [lt for tp, _, lt, _ in msgs if tp == "/trajectories"] == [round(s * DT * 1e9) for s in (0, 225, 450)]
    for i, e in enumerate(_scene_at(msgs, "/trajectories", 450).entities):
        pts = _xy(e.lines[0].points)
        assert 150 <= len(pts) <= 200
        assert np.allclose(pts[[0, -1]], pos[[0, 450], i], atol=1 / 256)
