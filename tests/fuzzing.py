"""What the ``test_fuzz_*`` files share: Hypothesis strategies for hostile inputs and the quick/soak twins.

Every fuzz property runs twice: a quick, derandomized pass in the default run (the same examples
every time, so CI stays fast and stable) and a randomized soak with many more examples behind
``-m slow``. Neither writes a Hypothesis database into the repository.
"""

from __future__ import annotations

import copy
import functools
import sys
from contextlib import contextmanager
from typing import Any, Callable

import numpy as np

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

_HEALTH = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much,
           HealthCheck.function_scoped_fixture]

#: Scalars a hostile or careless file holds: huge and negative integers, NaN, ±inf, -0.0, bools
#: (an int subtype), numeric strings, empty strings.
SCALARS = (st.none() | st.booleans() | st.integers() | st.sampled_from([0, -1, 1, 2**31, 2**63, 10**400, -10**30])
           | st.floats() | st.sampled_from([float("nan"), float("inf"), -0.0, 1e308, 5e-324])
           | st.text(max_size=12) | st.sampled_from(["", "1", "1e999", "nan", "../../etc/passwd", "train"]))

#: Any JSON-like value (lists and string-keyed dicts, nested a little).
JSON = st.recursive(SCALARS, lambda c: st.lists(c, max_size=5) | st.dictionaries(st.text(max_size=10), c, max_size=5),
                    max_leaves=25)


@contextmanager
def subnormals_on():
    """Hypothesis refuses to draw floats while the CPU flushes subnormals to zero, which training and
    policy loading turn on for the whole process (``torch.set_flush_denormal``); undo it meanwhile."""
    torch = sys.modules.get("torch")
    flushing = bool(np.multiply(np.float32(1e-40), np.float32(1.0)) == 0)
    if torch is None or not flushing:
        yield
        return
    torch.set_flush_denormal(False)
    try:
        yield
    finally:
        torch.set_flush_denormal(True)


def twins(prop: Callable, quick: int, soak: int, **strategies) -> tuple[Callable, Callable]:
    """(quick test, soak test) of property ``prop`` over ``strategies`` (keyword arguments)."""
    def make(n: int, derandomize: bool) -> Callable:
        test = settings(max_examples=n, deadline=None, derandomize=derandomize, database=None,
                        suppress_health_check=_HEALTH)(given(**strategies)(prop))

        @functools.wraps(test)
        def run(*args, **kwargs):
            with subnormals_on():
                return test(*args, **kwargs)
        return run
    return make(quick, True), pytest.mark.slow(make(soak, False))


def _paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(value, dict):
        for k, v in value.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            out += _paths(v, prefix + (i,))
    return out


def mutate(data: st.DataObject, value: Any, rounds: int = 3) -> Any:
    """A copy of JSON ``value`` with up to ``rounds`` nodes replaced by hostile values, deleted,
    duplicated, wrapped in a list or given another type — each choice drawn from ``data``."""
    value = copy.deepcopy(value)
    for _ in range(data.draw(st.integers(1, rounds))):
        path = data.draw(st.sampled_from(_paths(value)))
        op = data.draw(st.sampled_from(["replace", "scalar", "delete", "wrap", "extra", "stringify"]))
        if not path:
            if op in ("replace", "scalar"):
                value = data.draw(JSON if op == "replace" else SCALARS)
            continue
        parent = value
        for k in path[:-1]:
            parent = parent[k]
        key, node = path[-1], parent[path[-1]]
        if op == "replace":
            parent[key] = data.draw(JSON)
        elif op == "scalar":
            parent[key] = data.draw(SCALARS)
        elif op == "delete":
            del parent[key]
        elif op == "wrap":
            parent[key] = [node]
        elif op == "extra" and isinstance(node, dict):
            node[data.draw(st.text(max_size=8))] = data.draw(SCALARS)
        elif op == "extra" and isinstance(node, list):
            node.append(data.draw(JSON))
        elif op == "stringify":
            parent[key] = str(node)
    return value


def damage(data: st.DataObject, blob: bytes) -> bytes:
    """``blob`` truncated, with bits flipped, with a stretch overwritten by random bytes, or replaced
    by random bytes altogether — drawn from ``data``."""
    op = data.draw(st.sampled_from(["truncate", "flip", "flips", "splice", "random", "empty-tail"]))
    b = bytearray(blob)
    if op == "truncate":
        return bytes(b[: data.draw(st.integers(0, max(len(b) - 1, 0)))])
    if op in ("flip", "flips"):
        for _ in range(1 if op == "flip" else data.draw(st.integers(2, 16))):
            i = data.draw(st.integers(0, len(b) - 1))
            b[i] ^= 1 << data.draw(st.integers(0, 7))
        return bytes(b)
    if op == "splice":
        i = data.draw(st.integers(0, len(b) - 1))
        chunk = data.draw(st.binary(min_size=1, max_size=64))
        b[i : i + len(chunk)] = chunk
        return bytes(b)
    if op == "empty-tail":
        return bytes(b[: len(b) // 2]) + bytes(len(b) - len(b) // 2)
    return data.draw(st.binary(max_size=4096))


def load_damaged_file(tmp_path_factory, data: st.DataObject, name: str, blob: bytes, load: Callable,
                      error: type) -> None:
    """Write ``blob`` damaged (:func:`damage`) to a file and ``load`` it: it loads, or refuses with
    ``error`` in one line that names the file."""
    path = tmp_path_factory.getbasetemp() / name
    path.write_bytes(damage(data, blob))
    try:
        load(path)
    except error as e:
        assert "\n" not in str(e) and str(path) in str(e)
