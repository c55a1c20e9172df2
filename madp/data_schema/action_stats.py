"""Action statistics of a dataset: the per-axis mean and (population) standard deviation of U0 in m/s
over every robot of every sample of the train split. They normalise actions for training and travel
inside the manifest (:mod:`.manifest`) and every checkpoint. :class:`ActionStatsAccumulator`
computes them exactly (integer arithmetic), so the result does not depend on batch sizes, shard order
or how parallel workers' partial sums are merged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, Mapping

import numpy as np

from .schema import ACTIONS_DTYPE, DataError, SampleBatch

__all__ = ["ActionStats", "ActionStatsAccumulator"]

# A float32 x equals M * 2**E with an integer |M| < 2**24 and E >= -172 (frexp's significand of
# the smallest subnormal 2**-149 is 2**23 * 2**-172). Scaling by 2**_SHIFT makes every value an
# integer, and squares integers after scaling by 2**(2 * _SHIFT).
_SHIFT = 172
# int64 group sums of squares (each < 2**48) are exact for up to 2**15 terms.
_BLOCK = 1 << 15


def _exact_scaled_sums(x: np.ndarray) -> tuple[int, int]:
    """Exact ``(sum(x) * 2**_SHIFT, sum(x**2) * 2**(2*_SHIFT))`` of float32 values as Python ints.

    Values are split into integer significands and exponents with ``np.frexp``, significands are
    summed per exponent in int64 (vectorised), and the per-exponent sums are shifted into Python
    integers. Nothing is rounded, so the result is independent of the order of the values.
    """
    total, total_sq = 0, 0
    x = np.ascontiguousarray(x, dtype=np.float32).ravel()
    for start in range(0, x.size, _BLOCK):
        m, e = np.frexp(x[start : start + _BLOCK].astype(np.float64))
        sig = (m * (1 << 24)).astype(np.int64)  # exact: float32 has a 24-bit significand
        exp = e.astype(np.int64) - 24
        order = np.argsort(exp, kind="stable")
        exp, sig = exp[order], sig[order]
        starts = np.concatenate(([0], np.flatnonzero(np.diff(exp)) + 1))
        sums = np.add.reduceat(sig, starts)
        sums_sq = np.add.reduceat(sig * sig, starts)
        for s, s2, ex in zip(sums.tolist(), sums_sq.tolist(), exp[starts].tolist()):
            total += s << (ex + _SHIFT)
            total_sq += s2 << (2 * (ex + _SHIFT))
    return total, total_sq


def _finite_number(a: Any) -> bool:
    """A JSON number that is finite as a float (an integer beyond float range is not)."""
    if isinstance(a, bool) or not isinstance(a, (int, float)):
        return False
    try:
        return math.isfinite(a)
    except OverflowError:
        return False


@dataclass(frozen=True)
class ActionStats:
    """Per-axis statistics of expert actions U0 (m/s), for normalisation.

    Attributes:
        mean: ``[2]`` mean of (u_x, u_y) in m/s.
        std: ``[2]`` population standard deviation in m/s (may be 0 for degenerate data;
            consumers dividing by it must guard).
        count: number of action vectors (samples × robots) the statistics cover.
    """

    mean: tuple[float, float]
    std: tuple[float, float]
    count: int

    def to_dict(self) -> dict:
        return {"count": self.count, "mean": list(self.mean), "std": list(self.std)}

    @staticmethod
    def from_dict(d: Any, where: str = "action_stats") -> "ActionStats":
        if not isinstance(d, Mapping) or set(d) != {"count", "mean", "std"}:
            raise DataError.at(where, "expected an object with keys count, mean, std")
        vecs = []
        for key in ("mean", "std"):
            v = d[key]
            if (
                not isinstance(v, list)
                or len(v) != 2
                or not all(_finite_number(a) for a in v)
            ):
                raise DataError.at(f"{where}.{key}", "expected a list of 2 finite numbers")
            vecs.append(tuple(float(a) for a in v))
        if any(s < 0 for s in vecs[1]):
            raise DataError.at(f"{where}.std", "expected non-negative values")
        count = d["count"]
        if not isinstance(count, int) or isinstance(count, bool) or count <= 0:
            raise DataError.at(f"{where}.count", "expected a positive integer")
        return ActionStats(mean=vecs[0], std=vecs[1], count=count)  # type: ignore[arg-type]


class ActionStatsAccumulator:
    """Exact, order-independent accumulation of per-axis action mean and std.

    Feed it actions ``[..., 2]`` float32 (e.g. ``batch.actions`` of every train batch) with
    :meth:`add` / :meth:`add_batch`, merge partial accumulators from parallel workers with
    :meth:`merge` (or ship them as JSON with :meth:`state` / :meth:`from_state`), and read the
    result with :meth:`result`. Sums are kept as exact integers, so identical sets of samples give
    bit-identical statistics whatever the order or batching.
    """

    NUM_AXES = 2

    def __init__(self) -> None:
        self.count = 0
        self._sum = [0] * self.NUM_AXES  # sum(u) * 2**_SHIFT per axis
        self._sum_sq = [0] * self.NUM_AXES  # sum(u**2) * 2**(2*_SHIFT) per axis

    def add(self, actions: np.ndarray) -> "ActionStatsAccumulator":
        """Accumulate an array of actions ``[..., 2]`` float32 (finite). Returns ``self``."""
        if not isinstance(actions, np.ndarray) or actions.dtype != ACTIONS_DTYPE or actions.shape[-1:] != (2,):
            got = f"{actions.dtype.name} {list(actions.shape)}" if isinstance(actions, np.ndarray) else type(actions).__name__
            raise DataError.at("actions", f"expected a float32 array [..., 2], got {got}")
        flat = actions.reshape(-1, self.NUM_AXES)
        if not np.isfinite(flat).all():
            raise DataError.at("actions", "expected finite values, found NaN/inf")
        for axis in range(self.NUM_AXES):
            s, s2 = _exact_scaled_sums(flat[:, axis])
            self._sum[axis] += s
            self._sum_sq[axis] += s2
        self.count += flat.shape[0]
        return self

    def add_batch(self, batch: SampleBatch) -> "ActionStatsAccumulator":
        """Accumulate the actions of every robot of every sample of ``batch``."""
        return self.add(batch.actions)

    def merge(self, other: "ActionStatsAccumulator") -> "ActionStatsAccumulator":
        """Add another accumulator's sums into this one (exact). Returns ``self``."""
        self.count += other.count
        for axis in range(self.NUM_AXES):
            self._sum[axis] += other._sum[axis]
            self._sum_sq[axis] += other._sum_sq[axis]
        return self

    def state(self) -> dict:
        """JSON-able exact state (big integers as decimal strings)."""
        return {"count": self.count, "sum": [str(v) for v in self._sum], "sum_sq": [str(v) for v in self._sum_sq]}

    @classmethod
    def from_state(cls, state: Mapping) -> "ActionStatsAccumulator":
        """Inverse of :meth:`state`."""
        acc = cls()
        try:
            acc.count = int(state["count"])
            acc._sum = [int(v) for v in state["sum"]]
            acc._sum_sq = [int(v) for v in state["sum_sq"]]
        except (KeyError, TypeError, ValueError) as e:
            raise DataError.at("action stats state", f"expected count, sum, sum_sq ({e})") from None
        if len(acc._sum) != cls.NUM_AXES or len(acc._sum_sq) != cls.NUM_AXES or acc.count < 0:
            raise DataError.at("action stats state", "expected 2 axes and a non-negative count")
        return acc

    def result(self) -> ActionStats:
        """Mean and population std per axis, each correctly rounded from the exact sums."""
        if self.count == 0:
            raise DataError.at("action_stats", "no actions accumulated (is the train split empty?)")
        n = self.count
        scale = 1 << _SHIFT
        means, stds = [], []
        for axis in range(self.NUM_AXES):
            s, q = self._sum[axis], self._sum_sq[axis]
            means.append(float(Fraction(s, n * scale)))
            var = Fraction(n * q - s * s, n * n * scale * scale)  # exact, >= 0
            stds.append(math.sqrt(float(var)))
        return ActionStats(mean=(means[0], means[1]), std=(stds[0], stds[1]), count=n)
