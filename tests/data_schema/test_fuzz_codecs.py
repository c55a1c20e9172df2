"""Fuzz the MCAP and Parquet decoders: a shard truncated, bit-flipped, overwritten with random
bytes, or well-formed but holding samples of the wrong types and shapes is read to the end, or
refused with a one-line DataError naming it — never another exception."""

from __future__ import annotations


import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import Writer

from madp.data_schema import DataError, check_shard, inspect_shard, iter_shard, sample_proto, write_shard

from ..fuzzing import damage, twins
from .conftest import random_episodes


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    """A small valid shard of each format, and its ShardInfo."""
    d = tmp_path_factory.mktemp("fuzz-shards")
    out = {}
    for fmt in ("mcap", "parquet"):
        info = write_shard(d / f"valid.{fmt}", random_episodes(num_robots=2, lengths=(3, 1, 2), with_extras=fmt == "mcap"))
        out[fmt] = (d / f"valid.{fmt}", info)
    return out


def read_or_refuse(path, info=None) -> None:
    """Every reader entry point on ``path``: the samples, the header, the check against ``info``."""
    for reader in (lambda: sum(b.num_samples for b in iter_shard(path)), lambda: inspect_shard(path),
                   lambda: check_shard(path, info) if info is not None else None):
        try:
            reader()
        except DataError as e:
            assert "\n" not in str(e) and str(path) in str(e), str(e)


def prop_damaged_bytes(shards, tmp_path_factory, data):
    fmt = data.draw(st.sampled_from(["mcap", "parquet"]))
    src, info = shards[fmt]
    path = tmp_path_factory.getbasetemp() / f"fuzz.{fmt}"
    path.write_bytes(damage(data, src.read_bytes()))
    read_or_refuse(path, info)


# --- well-formed files, hostile content -----------------------------------------------------------
TENSOR_FIELDS = ("actions", "positions", "observations")


def hostile_sample(data, payload: bytes) -> bytes:
    """The sample message with one field given a wrong dtype, shape, data length or value."""
    msg = sample_proto.Sample()
    msg.ParseFromString(payload)
    op = data.draw(st.sampled_from(["dtype", "shape", "data", "version", "raw"]))
    t = getattr(msg, data.draw(st.sampled_from(TENSOR_FIELDS)))
    if op == "dtype":
        t.dtype = data.draw(st.sampled_from(["float64", "int8", "", "float16", "float32", ">f4", "object", "U10"]))
    elif op == "shape":
        t.ClearField("shape")
        t.shape.extend(data.draw(st.lists(st.integers(0, 2**32 - 1), max_size=6)))
    elif op == "data":
        t.data = data.draw(st.binary(max_size=64)) if data.draw(st.booleans()) else t.data[:-1]
    elif op == "version":
        msg.schema_version = data.draw(st.integers(0, 2**32 - 1))
    else:
        return data.draw(st.binary(max_size=200))
    return msg.SerializeToString()


def prop_hostile_mcap_samples(shards, tmp_path_factory, data):
    src, _ = shards["mcap"]
    path = tmp_path_factory.getbasetemp() / "hostile.mcap"
    victim = data.draw(st.integers(0, 5))
    with open(src, "rb") as f_in, open(path, "wb") as f_out:
        reader = make_reader(f_in)
        w = Writer(f_out)
        w.start(profile="", library="fuzz")
        schemas, channels, k = {}, {}, 0
        for schema, channel, message in reader.iter_messages():
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                          schemas[schema.id], channel.metadata)
            payload = message.data
            if channel.topic == "/madp/sample":
                payload = hostile_sample(data, payload) if k == victim else payload
                k += 1
            w.add_message(channels[channel.id], message.log_time, payload, message.publish_time, message.sequence)
        for m in reader.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        w.finish()
    read_or_refuse(path)


def prop_hostile_parquet_columns(shards, tmp_path_factory, data):
    src, _ = shards["parquet"]
    table = pq.read_table(src)
    path = tmp_path_factory.getbasetemp() / "hostile.parquet"
    name = data.draw(st.sampled_from(table.column_names))
    n = table.num_rows
    op = data.draw(st.sampled_from(["drop", "int", "float", "string", "nulls", "short-binary", "slice"]))
    if op == "drop":
        table = table.drop_columns([name])
    elif op == "slice":
        table = table.slice(0, data.draw(st.integers(0, n)))
    else:
        col = {"int": pa.array(np.arange(n, dtype=np.int64) * data.draw(st.integers(-2**40, 2**40))),
               "float": pa.array(np.full(n, data.draw(st.floats()))),
               "string": pa.array([data.draw(st.text(max_size=5)) for _ in range(n)]),
               "nulls": pa.nulls(n, type=table.schema.field(name).type),
               "short-binary": pa.array([b"\x00" * data.draw(st.integers(0, 9)) for _ in range(n)], pa.binary())}[op]
        table = table.set_column(table.column_names.index(name), pa.field(name, col.type), col)
    table = table.replace_schema_metadata(pq.read_schema(src).metadata)
    pq.write_table(table, path)
    read_or_refuse(path)


test_damaged_shard_bytes, test_damaged_shard_bytes_soak = twins(prop_damaged_bytes, 200, 4000, data=st.data())
test_hostile_mcap_samples, test_hostile_mcap_samples_soak = twins(prop_hostile_mcap_samples, 80, 1500, data=st.data())
test_hostile_parquet_columns, test_hostile_parquet_columns_soak = twins(prop_hostile_parquet_columns, 80, 1500,
                                                                          data=st.data())


def test_the_valid_shards_read(shards):
    for fmt, (path, info) in shards.items():
        check_shard(path, info)
        assert sum(b.num_samples for b in iter_shard(path)) == info.num_samples == 6
