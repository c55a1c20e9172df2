"""A policy checkpoint in float16, split into parts of bounded size, and joined back on load.

What ships from a GPU run (``scripts/gpu_paper.sh``) must fit in files of at most 16 MiB. The
``paper`` MADP is ~60 MB in float32, so it travels as::

    policy-fp16.safetensors.parts.json   the index: {"format", "file", "bytes", "sha256",
                                         "parts": [{"name", "bytes", "sha256"}, ...]}
    policy-fp16.safetensors.000          bytes 0 .. P-1 of the joined safetensors file
    policy-fp16.safetensors.001          bytes P .. 2P-1, and so on

The joined file is an ordinary policy file (same metadata) whose parameters are float16; buffers
(action statistics, BatchNorm statistics) keep their dtype. A file that fits in one part is written
whole, without an index. :func:`read_parts` takes the index or any part, checks every part's size
and sha256 and the whole's, and returns the metadata and the tensors, floats as float32 (CPU
inference runs in float32). A missing, truncated or damaged part is a one-line error naming it.

``python -m madp.policies.fp16 POLICY OUT [--part-mib 16]`` writes OUT (or OUT's index and parts):
:mod:`madp.policies.fp16`. This module reads and writes the file format only; building a model from
the joined file is :mod:`madp.policies.checkpoint`'s job, which imports this one (never the reverse).
"""

from __future__ import annotations

import hashlib
import json
import re
import struct
from pathlib import Path

import torch
from safetensors.torch import load as load_safetensors_bytes
from safetensors.torch import save as save_safetensors_bytes
from torch import nn

from madp.errors import InputError
from madp.io.atomic import atomic_path, write_text_atomic

FORMAT = "madp-policy-parts/1"
INDEX_SUFFIX = ".parts.json"
MAX_PART_BYTES = 16 << 20  # 16 MiB
_PART = re.compile(r"^(?P<base>.+)\.(?P<i>\d{3})$")


def index_path(path: str | Path) -> Path | None:
    """The index of the parts ``path`` names: the index itself (``*.parts.json``) or one of its parts
    (``NAME.NNN``: three digits); None for any other name (a plain policy file)."""
    path = Path(path)
    if path.name.endswith(INDEX_SUFFIX):
        return path
    m = _PART.match(path.name)
    if m is None:
        return None
    index = path.with_name(m["base"] + INDEX_SUFFIX)
    if not index.is_file():
        raise FileNotFoundError(f"{index}: missing; it lists the parts of {m['base']}, of which {path.name} is one")
    return index


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _read_index(index: Path) -> dict:
    if not index.is_file():
        raise FileNotFoundError(f"{index}: checkpoint index not found")
    try:
        doc = json.loads(index.read_text())
    except (OSError, ValueError, UnicodeDecodeError) as e:
        raise InputError(f"{index}: not a readable index of checkpoint parts ({type(e).__name__})") from None
    parts = doc.get("parts") if isinstance(doc, dict) else None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(parts, list) or not parts:
        raise InputError(f"{index}: not an index of checkpoint parts (expected format {FORMAT!r} and a list of parts)")
    for i, p in enumerate(parts):
        ok = (isinstance(p, dict) and isinstance(p.get("name"), str) and Path(p["name"]).name == p["name"]
              and p["name"] not in ("", ".", "..") and isinstance(p.get("bytes"), int) and isinstance(p.get("sha256"), str))
        if not ok:
            raise InputError(f"{index}: part {i + 1} is malformed (expected a file name beside the index, bytes, sha256)")
    if not isinstance(doc.get("bytes"), int) or not isinstance(doc.get("sha256"), str):
        raise InputError(f"{index}: lacks the joined file's bytes and sha256")
    return doc


def join_parts(index: Path) -> bytes:
    """The joined bytes of the parts ``index`` lists, each part's size and sha256 checked, then the whole's."""
    doc = _read_index(index)
    n, chunks = len(doc["parts"]), []
    for i, p in enumerate(doc["parts"]):
        part = index.parent / p["name"]
        what = f"part {i + 1} of {n} of {doc.get('file', index.name)}"
        if not part.is_file():
            raise FileNotFoundError(f"{part}: {what} is missing")
        data = part.read_bytes()
        if len(data) != p["bytes"]:
            raise InputError(f"{part}: {what} has {len(data)} bytes, expected {p['bytes']} (truncated or replaced)")
        if _sha256(data) != p["sha256"]:
            raise InputError(f"{part}: {what} is damaged (sha256 differs from the index {index.name})")
        chunks.append(data)
    blob = b"".join(chunks)
    if len(blob) != doc["bytes"] or _sha256(blob) != doc["sha256"]:
        raise InputError(f"{index}: the joined parts do not match the index's size and sha256")
    return blob


def _metadata(blob: bytes, source: Path) -> dict[str, str]:
    """The ``__metadata__`` of a safetensors file's bytes (its header: u64 length, then JSON)."""
    try:
        (n,) = struct.unpack("<Q", blob[:8])
        header = json.loads(blob[8:8 + n])
        meta = header.get("__metadata__") or {}
        if not isinstance(meta, dict):
            raise ValueError("metadata is not an object")
        return meta
    except (struct.error, ValueError, UnicodeDecodeError, AttributeError) as e:
        raise InputError(f"{source}: the joined parts are not a readable safetensors checkpoint ({type(e).__name__})") from None


def read_parts(path: str | Path, device: str | torch.device = "cpu") -> tuple[dict[str, str], dict] | None:
    """``(metadata, tensors on device)`` of the checkpoint whose parts ``path`` names (index or a
    part), floating tensors as float32; None when ``path`` is a plain file (not split)."""
    index = index_path(path)
    if index is None:
        return None
    blob = join_parts(index)
    metadata = _metadata(blob, index)
    try:
        state = load_safetensors_bytes(blob)
    except Exception as e:  # safetensors' own error types
        raise InputError(f"{index}: the joined parts are not a readable safetensors checkpoint ({type(e).__name__})") from None
    return metadata, {k: (v.float() if v.is_floating_point() else v).to(device) for k, v in state.items()}


def fp16_state(model: nn.Module) -> dict[str, torch.Tensor]:
    """``model``'s state dict on the CPU with its parameters in float16 (buffers unchanged). A
    parameter beyond float16's range is a ValueError naming it."""
    params = {name for name, _ in model.named_parameters()}
    out = {}
    for k, v in model.state_dict().items():
        v = v.detach().to("cpu")
        if k in params and v.is_floating_point():
            h = v.half()
            if not bool(torch.isfinite(h).all()) and bool(torch.isfinite(v).all()):
                raise ValueError(f"weight '{k}' exceeds float16's range (max |w| = {float(v.abs().max()):.3g})")
            v = h
        out[k] = v.contiguous()
    return out


def write_fp16(model: nn.Module, metadata: dict[str, str], out: str | Path,
               max_part_bytes: int = MAX_PART_BYTES) -> list[Path]:
    """Write ``model`` (parameters in float16, ``metadata`` as the policy file's) as ``out``, or, when
    larger than ``max_part_bytes``, as ``out``'s index and parts. Returns the files written (the index
    first). Refuses to replace an existing ``out`` or index."""
    out = Path(out)
    index = out.with_name(out.name + INDEX_SUFFIX)
    for p in (out, index):
        if p.exists():
            raise FileExistsError(f"{p}: exists; remove it or choose another output")
    if max_part_bytes < 1:
        raise ValueError(f"--part-mib: expected a positive size, got {max_part_bytes} bytes")
    blob = save_safetensors_bytes(fp16_state(model), metadata={**metadata, "weights_dtype": json.dumps("float16")})
    out.parent.mkdir(parents=True, exist_ok=True)
    if len(blob) <= max_part_bytes:
        with atomic_path(out) as tmp:
            tmp.write_bytes(blob)
        return [out]
    chunks = [blob[i:i + max_part_bytes] for i in range(0, len(blob), max_part_bytes)]
    if len(chunks) > 1000:
        raise InputError(f"{out}: {len(chunks)} parts; at most 1000 (use larger parts)")
    written, parts = [], []
    for i, chunk in enumerate(chunks):
        part = out.with_name(f"{out.name}.{i:03d}")
        with atomic_path(part) as tmp:
            tmp.write_bytes(chunk)
        written.append(part)
        parts.append({"name": part.name, "bytes": len(chunk), "sha256": _sha256(chunk)})
    doc = {"format": FORMAT, "file": out.name, "bytes": len(blob), "sha256": _sha256(blob), "parts": parts}
    write_text_atomic(index, json.dumps(doc, indent=1) + "\n")  # last: parts without an index are not a checkpoint
    return [index, *written]
