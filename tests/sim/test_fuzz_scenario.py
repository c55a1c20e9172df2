"""Fuzz the scenario loader: any JSON (or bytes) in a scenario file gives a Scenario or a one-line
ScenarioError — never another exception."""

from __future__ import annotations

import json

import pytest
from hypothesis import strategies as st

from madp.sim import Scenario, params
from madp.sim.scenario import ScenarioError

from ..fuzzing import JSON, load_damaged_file, mutate, twins

#: A valid scenario on a small world (its importance map is cheap to build).
VALID = {"features": [{"mean": [100.0, 120.0], "sigma": 40.0, "peak": 0.8}, {"mean": [200, 30], "sigma": 50, "peak": 1}],
         "robots": [[10.0, 10.0], [200.0, 200.0], [128, 5]], "params": {"world_size": 256, "comm_radius_m": 128},
         "name": "fuzz", "seed": 3, "source": "hand-made"}


@pytest.fixture(scope="module", autouse=True)
def small_machine():
    """Pretend the machine has 1 GiB, so a fuzzed size is refused instead of allocated."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(params, "physical_memory_bytes", lambda: 1 << 30)
        yield


def loads_or_refuses(d) -> None:
    try:
        sc = Scenario.from_dict(d, "fuzz.json")
    except ScenarioError as e:
        assert "\n" not in str(e) and str(e).startswith("fuzz.json")
        return
    assert len(sc.robots_m) >= 1 and sc.features.shape[1] == 4


def prop_any_json(doc):
    loads_or_refuses(doc)


def prop_mutated_scenario(data):
    loads_or_refuses(mutate(data, VALID))


def prop_damaged_file(tmp_path_factory, data):
    load_damaged_file(tmp_path_factory, data, "fuzz-scenario.json", json.dumps(VALID).encode(), Scenario.load,
                      ScenarioError)


test_any_json_document, test_any_json_document_soak = twins(prop_any_json, 150, 3000, doc=JSON)
test_mutated_scenario, test_mutated_scenario_soak = twins(prop_mutated_scenario, 250, 5000, data=st.data())
test_damaged_scenario_file, test_damaged_scenario_file_soak = twins(prop_damaged_file, 100, 2000, data=st.data())


def test_the_valid_scenario_loads():
    assert len(Scenario.from_dict(VALID).robots_m) == 3


@pytest.mark.parametrize("doc", [
    {**VALID, "robots": [[10**400, 5]]},  # found by the soak: OverflowError
    {**VALID, "seed": True},
    {**VALID, "params": {"world_size": 16 * 10**9}},  # refused by size, never allocated
    {**VALID, "params": {"world_size": 2**70}},
    {**VALID, "features": [{"mean": [10**400, 1], "sigma": 1, "peak": 1}]},
    {**VALID, "features": [{"mean": [1, 1], "sigma": 8.98846567431158e307, "peak": 1}]},  # soak: OverflowError
])
def test_cases_the_fuzzers_found(doc):
    with pytest.raises(ScenarioError):
        Scenario.from_dict(doc, "fuzz.json")


def test_non_utf8_scenario_file_is_named(tmp_path):  # found by the quick pass: UnicodeDecodeError
    p = tmp_path / "s.json"
    p.write_bytes(b"\x80{}")
    with pytest.raises(ScenarioError, match="s.json"):
        Scenario.load(p)
