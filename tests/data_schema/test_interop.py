"""Shards are readable by standard tools: mcap + its protobuf decoder, Foxglove schemas, DuckDB, pandas."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from madp.data_schema import write_shard
from madp.data_schema import sample_proto
from madp.data_schema.foxglove_viz import downsample_map


@pytest.fixture(scope="module")
def mcap_path(tmp_path_factory, real_episodes):
    path = tmp_path_factory.mktemp("interop") / "s.mcap"
    write_shard(path, real_episodes)
    return path


@pytest.fixture(scope="module")
def parquet_path(tmp_path_factory, real_episodes):
    path = tmp_path_factory.mktemp("interop") / "s.parquet"
    write_shard(path, real_episodes)
    return path


def test_mcap_topics_and_schemas(mcap_path, real_episodes):
    from mcap.reader import make_reader

    with open(mcap_path, "rb") as f:
        summary = make_reader(f).get_summary()
    topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert topics == {
        "/madp/sample": "madp.Sample",
        "/world/map": "foxglove.Grid",
        "/robots": "foxglove.SceneUpdate",
        "/expert/goals": "foxglove.SceneUpdate",
        "/expert/actions": "foxglove.SceneUpdate",
    }
    counts = {c.topic: summary.statistics.channel_message_counts[c.id] for c in summary.channels.values()}
    assert counts["/madp/sample"] == counts["/robots"] == 40
    assert counts["/world/map"] == len(real_episodes)
    assert all(s.encoding == "protobuf" for s in summary.schemas.values())


def test_mcap_is_self_describing(mcap_path, real_episodes):
    """The generic protobuf decoder, knowing nothing of madp, decodes samples and Foxglove messages."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    first: dict = {}
    with open(mcap_path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            first.setdefault(channel.topic, (schema.name, message.log_time, decoded))
    ep = real_episodes[0]

    name, log_time, sample = first["/madp/sample"]
    assert type(sample).DESCRIPTOR.full_name == "madp.Sample"
    assert (sample.schema_version, sample.episode_id, sample.step, sample.scenario_seed) == (1, ep.episode_id, 0, ep.scenario_seed)
    obs = np.frombuffer(sample.observations.data, dtype=sample.observations.dtype).reshape(sample.observations.shape)
    assert obs.tobytes() == ep.observations[0].tobytes()

    name, log_time, grid = first["/world/map"]
    assert name == "foxglove.Grid"
    assert grid.frame_id == "world" and grid.fields[0].name == "importance"
    expected, factor = downsample_map(ep.world_map)
    assert grid.column_count == expected.shape[0] and grid.cell_size.x == pytest.approx(factor)
    assert np.frombuffer(grid.data, "<f4").reshape(expected.shape[1], expected.shape[0]).T.tobytes() == expected.tobytes()

    name, log_time, scene = first["/robots"]
    assert name == "foxglove.SceneUpdate"
    spheres = scene.entities[0].spheres
    assert len(spheres) == 32
    assert spheres[5].pose.position.x == pytest.approx(float(ep.positions[0, 5, 0]))
    assert scene.entities[0].timestamp.seconds * 10**9 + scene.entities[0].timestamp.nanos == log_time

    name, _, goals = first["/expert/goals"]
    pts = goals.entities[0].lines[0].points
    assert len(pts) == 64 and pts[1].x == pytest.approx(float(ep.goals[0, 0, 0]))


def test_mcap_log_times_are_simulated_time(mcap_path, real_episodes):
    from mcap.reader import make_reader

    with open(mcap_path, "rb") as f:
        times = [m.log_time for _, c, m in make_reader(f).iter_messages(topics=["/madp/sample"])]
    steps = np.concatenate([e.steps for e in real_episodes])
    t0 = np.asarray(times[: real_episodes[0].num_steps])
    assert np.array_equal(t0, steps[: len(t0)] * 200_000_000)  # episode 0 starts at t = 0
    assert np.all(np.diff(times) > 0)


def test_downsample_map_block_mean():
    m = np.arange(16, dtype=np.float32).reshape(4, 4)
    g, f = downsample_map(m, max_cells=2)
    assert f == 2 and g.tolist() == [[2.5, 4.5], [10.5, 12.5]]
    g, f = downsample_map(np.zeros((6, 6), np.float32), max_cells=4)  # ceil(6/4)=2 divides 6
    assert f == 2 and g.shape == (3, 3)


def test_parquet_readable_by_duckdb(parquet_path):
    duckdb = pytest.importorskip("duckdb")
    con = duckdb.connect()
    assert con.sql(f"SELECT count(*) FROM '{parquet_path}'").fetchall() == [(40,)]
    n_ep, obs_len, act_len = con.sql(
        f"SELECT count(DISTINCT episode_id), max(octet_length(observations)), max(len(actions)) FROM '{parquet_path}'"
    ).fetchall()[0]
    assert (n_ep, obs_len, act_len) == (3, 32 * 4 * 32 * 32 * 2, 64)


def test_parquet_readable_by_pandas(parquet_path, real_episodes):
    pd = pytest.importorskip("pandas")
    df = pd.read_parquet(parquet_path)
    assert list(df.columns) == ["episode_id", "step", "scenario_seed", "actions", "positions", "observations"]
    assert len(df) == 40
    row = df.iloc[17]
    ep = real_episodes[1]
    assert row.episode_id == ep.episode_id and row.step == ep.steps[1]
    assert np.frombuffer(row.observations, "<f2").tobytes() == ep.observations[1].tobytes()
    assert np.asarray(row.actions, np.float32).tobytes() == ep.actions[1].tobytes()


def test_proto_file_matches_python_descriptor():
    """sample.proto (documentation) and the descriptor built in Python (used) stay identical."""
    text = (Path(sample_proto.__file__).parent / "sample.proto").read_text()
    fdp = sample_proto.build_file_descriptor_proto()
    type_names = {4: "uint64", 9: "string", 12: "bytes", 13: "uint32", 11: None}
    for msg in fdp.message_type:
        body = re.search(r"message %s \{(.*?)\n\}" % msg.name, text, re.S).group(1)
        declared = re.findall(r"^\s*(repeated )?(\w+) (\w+) = (\d+);", body, re.M)
        want = []
        for f in msg.field:
            tname = type_names[f.type] or f.type_name.split(".")[-1]
            want.append(("repeated " if f.label == 3 else "", tname, f.name, str(f.number)))
        assert declared == want, msg.name
    assert 'package madp;' in text and 'syntax = "proto3";' in text
