"""Action statistics (``madp.data_schema.action_stats``): exact, order-independent sums that match a
float64 reference, and the refusals of the accumulator and of ``ActionStats.from_dict``, message for
message (written against the mutants mutmut left alive: an off-by-one in an exact integer
sum vanishes in rounding everywhere except at a variance of exactly zero)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from madp.data_schema import ActionStatsAccumulator, DataError
from madp.data_schema.action_stats import ActionStats, _exact_scaled_sums



def test_action_stats_match_float64_reference():
    rng = np.random.default_rng(0)
    u = rng.uniform(-5, 5, (500, 32, 2)).astype(np.float32)
    stats = ActionStatsAccumulator().add(u).result()
    ref = u.reshape(-1, 2).astype(np.float64)
    np.testing.assert_allclose(stats.mean, ref.mean(axis=0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(stats.std, ref.std(axis=0), rtol=1e-12)
    assert stats.count == 500 * 32


def test_action_stats_exact_and_order_independent():
    rng = np.random.default_rng(1)
    # wide dynamic range, subnormals and exact cancellation: float64 sums would depend on order
    u = np.concatenate(
        [
            rng.uniform(-5, 5, (300, 2)),
            np.array([[1e30, -1e30], [-1e30, 1e30], [1e-45, -1e-45], [3.0, 4.0]]),
        ]
    ).astype(np.float32)
    whole = ActionStatsAccumulator().add(u).result()
    perm = u[rng.permutation(len(u))]
    parts = [ActionStatsAccumulator().add(perm[i : i + 37]) for i in range(0, len(perm), 37)]
    merged = ActionStatsAccumulator()
    for p in reversed(parts):
        merged.merge(ActionStatsAccumulator.from_state(json.loads(json.dumps(p.state()))))
    assert merged.result() == whole  # bit-identical floats
    # exact mean of a set whose float64 running sum loses the small values
    tiny = np.array([[1e30, 1.0], [1.0, 1.0], [-1e30, 1.0]], np.float32)
    assert ActionStatsAccumulator().add(tiny).result().mean[0] == pytest.approx(1.0 / 3.0, rel=1e-15)


def test_action_stats_refuses_bad_input():
    with pytest.raises(DataError, match="expected a float32 array"):
        ActionStatsAccumulator().add(np.zeros((3, 2)))
    with pytest.raises(DataError, match="finite"):
        ActionStatsAccumulator().add(np.full((3, 2), np.nan, np.float32))
    with pytest.raises(DataError, match="no actions"):
        ActionStatsAccumulator().result()


# --- the contract (mutation survivors) ------------------------------------------------------------

def _message(fn, *args, **kwargs) -> str:
    with pytest.raises(DataError) as exc:
        fn(*args, **kwargs)
    return str(exc.value)


def test_constant_actions_have_exactly_zero_std():
    """Guards the exact integer sums: any non-zero start of the sums of squares (``total_sq = 1``,
    ``_sum_sq = [1, 1]``) leaves a variance of ~2**-344 instead of 0, so std is no longer 0.0."""
    u = np.full((7, 2), 1.5, np.float32)
    stats = ActionStatsAccumulator().add(u).result()
    assert stats.std == (0.0, 0.0) and stats.mean == (1.5, 1.5) and stats.count == 7


def test_exact_sums_round_their_input_to_float32():
    """Guards ``dtype=np.float32``: the sums are of float32 values even when given float64."""
    s, s2 = _exact_scaled_sums(np.array([0.1, 0.1]))
    x = float(np.float32(0.1))
    assert s == int(2 * x * 2**172) and s2 == int(2 * x * x * 2 ** (2 * 172))


def test_repeated_adds_accumulate():
    """Guards ``+=`` in :meth:`ActionStatsAccumulator.add` (mutants assign the last batch only)."""
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(5, 2)).astype(np.float32), rng.normal(2, 3, size=(9, 2)).astype(np.float32)
    two = ActionStatsAccumulator().add(a).add(b).result()
    assert two == ActionStatsAccumulator().add(np.concatenate([a, b])).result()
    assert two.count == 14


@pytest.mark.parametrize(
    "actions, message",
    [
        (np.zeros((3, 2)), "actions: expected a float32 array [..., 2], got float64 [3, 2]"),
        (np.zeros((3, 3), np.float32), "actions: expected a float32 array [..., 2], got float32 [3, 3]"),
        ([[0.0, 1.0]], "actions: expected a float32 array [..., 2], got list"),
        (np.array([[0.0, np.inf]], np.float32), "actions: expected finite values, found NaN/inf"),
    ],
)
def test_accumulator_refusals(actions, message):
    assert _message(ActionStatsAccumulator().add, actions) == message


def test_accumulator_state_round_trip_and_refusals():
    """An empty accumulator's state is valid (count 0); malformed states name what was expected."""
    empty = ActionStatsAccumulator.from_state(ActionStatsAccumulator().state())
    assert empty.count == 0
    assert _message(empty.result) == "action_stats: no actions accumulated (is the train split empty?)"
    good = ActionStatsAccumulator().add(np.ones((2, 2), np.float32)).state()
    assert ActionStatsAccumulator.from_state(good).result().count == 2
    assert _message(ActionStatsAccumulator.from_state, {"count": 1, "sum": ["0", "0"]}) == (
        "action stats state: expected count, sum, sum_sq ('sum_sq')"
    )
    bad_axes = "action stats state: expected 2 axes and a non-negative count"
    for state in (
        {**good, "sum": ["0", "0", "0"]},
        {**good, "sum_sq": ["0"]},
        {**good, "count": -1},
    ):
        assert _message(ActionStatsAccumulator.from_state, state) == bad_axes


@pytest.mark.parametrize(
    "d, message",
    [
        ([1, 2], "expected an object with keys count, mean, std"),
        ({"count": 1, "mean": [0, 0]}, "expected an object with keys count, mean, std"),
        ({"count": 1, "mean": [0, 0], "std": [1.0]}, ".std: expected a list of 2 finite numbers"),
        ({"count": 1, "mean": [0, float("nan")], "std": [1, 1]}, ".mean: expected a list of 2 finite numbers"),
        ({"count": 1, "mean": [0, 0], "std": [1, -0.5]}, ".std: expected non-negative values"),
        ({"count": 0, "mean": [0, 0], "std": [1, 1]}, ".count: expected a positive integer"),
        ({"count": True, "mean": [0, 0], "std": [1, 1]}, ".count: expected a positive integer"),
        ({"count": 2.0, "mean": [0, 0], "std": [1, 1]}, ".count: expected a positive integer"),
    ],
)
def test_action_stats_refusals(d, message):
    got = _message(ActionStats.from_dict, d, "m.json: action_stats")
    sep = ": " if not message.startswith(".") else ""
    assert got == f"m.json: action_stats{sep}{message}"


def test_action_stats_errors_name_action_stats_by_default():
    assert _message(ActionStats.from_dict, {}) == "action_stats: expected an object with keys count, mean, std"


def test_action_stats_accepts_zero_std_and_count_one():
    """Boundaries: std 0 (degenerate data) and a count of 1 are valid."""
    s = ActionStats.from_dict({"count": 1, "mean": [0, 0], "std": [0.0, 0.25]})
    assert s == ActionStats(mean=(0.0, 0.0), std=(0.0, 0.25), count=1)
