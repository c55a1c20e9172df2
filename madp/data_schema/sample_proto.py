"""The ``madp.Sample`` protobuf message, built in Python at import (no protoc, no generated code).

The descriptor mirrors ``sample.proto`` beside this file (a test keeps them identical). It lives
in a private :class:`~google.protobuf.descriptor_pool.DescriptorPool` so it cannot clash with other
code that defines ``madp.*`` types. :data:`FILE_DESCRIPTOR_SET` is the serialized
``FileDescriptorSet`` embedded as the MCAP schema, which makes shards self-describing.

Tensors are raw little-endian bytes in C order; :func:`tensor_to_numpy` decodes them with
``np.frombuffer`` (no per-element Python work).
"""

from __future__ import annotations

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool
from google.protobuf.message_factory import GetMessageClass

from .schema import DataError

#: MCAP schema name / protobuf full name of a sample.
SAMPLE_SCHEMA_NAME = "madp.Sample"
#: Name of the virtual .proto file inside the descriptor set.
PROTO_FILE_NAME = "madp/sample.proto"

_F = descriptor_pb2.FieldDescriptorProto

#: (message, [(field name, number, type, label, type_name)]) — the single source of the layout.
_MESSAGES = (
    (
        "Tensor",
        (
            ("dtype", 1, _F.TYPE_STRING, _F.LABEL_OPTIONAL, None),
            ("shape", 2, _F.TYPE_UINT32, _F.LABEL_REPEATED, None),
            ("data", 3, _F.TYPE_BYTES, _F.LABEL_OPTIONAL, None),
        ),
    ),
    (
        "Sample",
        (
            ("schema_version", 1, _F.TYPE_UINT32, _F.LABEL_OPTIONAL, None),
            ("episode_id", 2, _F.TYPE_UINT64, _F.LABEL_OPTIONAL, None),
            ("step", 3, _F.TYPE_UINT64, _F.LABEL_OPTIONAL, None),
            ("scenario_seed", 4, _F.TYPE_UINT64, _F.LABEL_OPTIONAL, None),
            ("actions", 5, _F.TYPE_MESSAGE, _F.LABEL_OPTIONAL, ".madp.Tensor"),
            ("positions", 6, _F.TYPE_MESSAGE, _F.LABEL_OPTIONAL, ".madp.Tensor"),
            ("observations", 7, _F.TYPE_MESSAGE, _F.LABEL_OPTIONAL, ".madp.Tensor"),
        ),
    ),
)


def build_file_descriptor_proto() -> descriptor_pb2.FileDescriptorProto:
    """The ``madp/sample.proto`` file descriptor (proto3, package ``madp``)."""
    fdp = descriptor_pb2.FileDescriptorProto(name=PROTO_FILE_NAME, package="madp", syntax="proto3")
    for msg_name, fields in _MESSAGES:
        msg = fdp.message_type.add(name=msg_name)
        for name, number, ftype, label, type_name in fields:
            f = msg.field.add(name=name, number=number, type=ftype, label=label, json_name=_json_name(name))
            if type_name:
                f.type_name = type_name
    return fdp


def _json_name(name: str) -> str:
    head, *rest = name.split("_")
    return head + "".join(p.capitalize() for p in rest)


_FILE_DESCRIPTOR_PROTO = build_file_descriptor_proto()
_POOL = descriptor_pool.DescriptorPool()
_POOL.Add(_FILE_DESCRIPTOR_PROTO)

#: Generated message classes.
Tensor = GetMessageClass(_POOL.FindMessageTypeByName("madp.Tensor"))
Sample = GetMessageClass(_POOL.FindMessageTypeByName(SAMPLE_SCHEMA_NAME))

#: Serialized ``FileDescriptorSet`` (the MCAP schema data for ``madp.Sample``).
FILE_DESCRIPTOR_SET: bytes = descriptor_pb2.FileDescriptorSet(file=[_FILE_DESCRIPTOR_PROTO]).SerializeToString(
    deterministic=True
)

#: numpy dtype for each dtype name allowed in a Tensor.
TENSOR_DTYPES = {"float32": np.dtype("<f4"), "float16": np.dtype("<f2")}


def tensor_from_numpy(tensor, array: np.ndarray) -> None:
    """Fill the ``Tensor`` message ``tensor`` in place from ``array`` (float32/float16)."""
    dt = np.dtype(array.dtype.newbyteorder("<"))
    name = dt.name
    if name not in TENSOR_DTYPES:
        raise DataError.at("Tensor", f"expected float32 or float16 data, got {array.dtype.name}")
    tensor.dtype = name
    tensor.shape.extend(array.shape)
    tensor.data = np.ascontiguousarray(array, dtype=TENSOR_DTYPES[name]).tobytes()


class TensorSpec:
    """Expected dtype and shape of one Tensor field, with a fast :meth:`decode`."""

    __slots__ = ("where", "dtype", "dtype_name", "shape", "nbytes")

    def __init__(self, where: str, dtype: np.dtype, shape: tuple[int, ...]):
        self.where = where
        self.dtype = np.dtype(dtype)
        self.dtype_name = self.dtype.name
        self.shape = tuple(int(s) for s in shape)
        self.nbytes = int(np.prod(self.shape)) * self.dtype.itemsize

    def decode(self, tensor) -> np.ndarray:
        """Read-only array view of ``tensor``'s bytes after checking dtype, shape and byte count.

        Raises :class:`DataError` naming ``where`` (file and field) on mismatch.
        """
        data = tensor.data
        if tensor.dtype != self.dtype_name or len(data) != self.nbytes or tuple(tensor.shape) != self.shape:
            if tensor.dtype != self.dtype_name:
                raise DataError.at(self.where, f"expected dtype {self.dtype_name}, got {tensor.dtype or 'none'!r}")
            if tuple(tensor.shape) != self.shape:
                raise DataError.at(self.where, f"expected shape {list(self.shape)}, got {list(tensor.shape)}")
            raise DataError.at(self.where, f"expected {self.nbytes} data bytes, got {len(data)}")
        return np.frombuffer(data, dtype=self.dtype).reshape(self.shape)


def tensor_to_numpy(tensor, where: str, dtype: np.dtype, shape: tuple[int, ...]) -> np.ndarray:
    """Decode ``tensor`` into a read-only array view after checking dtype, shape and byte count.

    ``where`` names the file and field in the :class:`DataError` raised on mismatch. For many
    tensors of one layout, build a :class:`TensorSpec` once instead.
    """
    return TensorSpec(where, dtype, shape).decode(tensor)


__all__ = [
    "FILE_DESCRIPTOR_SET",
    "PROTO_FILE_NAME",
    "SAMPLE_SCHEMA_NAME",
    "Sample",
    "TENSOR_DTYPES",
    "Tensor",
    "TensorSpec",
    "build_file_descriptor_proto",
    "tensor_from_numpy",
    "tensor_to_numpy",
]
