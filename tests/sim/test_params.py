"""SimParams' contract: which values are refused, with which one-line message (unknown parameters
included), and the memory estimate ``check_fits`` compares with the machine's memory.

Written against the mutants mutmut left alive in ``madp/sim/params.py``; each test names the mutants
it kills (``__post_init__`` mutants are written ``_N``). The messages are what a user sees when a flag
or a JSON file holds a bad value, so they are pinned whole."""

from __future__ import annotations

import numpy as np
import pytest

from madp.sim import Scenario, ScenarioError, SimParams
from madp.sim import params as params_mod
from madp.sim.params import physical_memory_bytes


def _refusal(**kw) -> str:
    with pytest.raises(ValueError) as e:
        SimParams(**kw)
    return str(e.value)


def test_physical_memory_is_known_on_linux():
    """x_physical_memory_bytes_3 (a misspelt sysconf name makes it None): Linux reports both."""
    m = physical_memory_bytes()
    assert isinstance(m, int) and m > 2**26


@pytest.mark.parametrize("field", ["sigma_range_m", "peak_range"])
@pytest.mark.parametrize("value", ["xy", (1.0, 2.0, 3.0), (40.0, "x"), (40.0, None), [1.0], (1.0, 10**400),
                                   (1.0, float("nan")), (True, 2.0)])
def test_pairs_are_checked_for_shape_and_type(field, value):
    """_8.._11 (the pair fields' names misspelt: not checked as pairs), _12, _13 (``or`` → ``and``),
    _20 (message dropped), x__is_number_1 (a bool counted a number), _3 (a non-number counted a
    number), _5 (an integer beyond float range counted finite)."""
    assert _refusal(**{field: value}) == f"{field} must be a (low, high) pair of finite numbers, got {value!r}"


@pytest.mark.parametrize("field", ["world_size", "num_robots", "num_features", "sensor_size", "history_size"])
@pytest.mark.parametrize("value", [2.5, True, "8", None])
def test_int_fields_refuse_non_integers(field, value):
    """_22, _23 (the ``"int"`` type name misspelt: ints unchecked), _24 (``or`` → ``and``), _26
    (message dropped)."""
    assert _refusal(**{field: value}) == f"{field} must be an integer, got {value!r}"


def test_int_fields_accept_numpy_integers_as_python_ints():
    p = SimParams(num_robots=np.int64(4), num_features=np.int32(3))
    assert (p.num_robots, p.num_features) == (4, 3)
    assert type(p.num_robots) is int and type(p.num_features) is int


@pytest.mark.parametrize("field", ["truncation_sigmas", "comm_radius_m", "max_speed_mps", "dt_s"])
@pytest.mark.parametrize("value", ["x", True, None, float("inf"), 10**400])
def test_float_fields_refuse_non_numbers(field, value):
    """_36, _37 (the ``"float"`` type name misspelt), _40 (message dropped), x__is_number_1, _3, _5."""
    assert _refusal(**{field: value}) == f"{field} must be a finite number, got {value!r}"


@pytest.mark.parametrize("value", [1, 0, "true", None])
def test_bool_field_refuses_non_bools(value):
    """_43, _44 (the ``"bool"`` type name misspelt), _46 (message dropped)."""
    assert _refusal(check_oscillations=value) == f"check_oscillations must be true or false, got {value!r}"


def test_pairs_are_stored_as_float_tuples():
    """_53, _54, _63, _64 (the normalised pair written to a misspelt attribute: a list stays a list)."""
    p = SimParams(sigma_range_m=[40, 60], peak_range=[1, 2])
    assert p.sigma_range_m == (40.0, 60.0) and p.peak_range == (1.0, 2.0)
    assert isinstance(p.sigma_range_m, tuple) and isinstance(p.peak_range, tuple)
    assert all(type(x) is float for x in p.sigma_range_m + p.peak_range)


@pytest.mark.parametrize("world_size", [1000, 128, 1010])
def test_world_size_must_be_a_multiple_of_16_at_least_the_local_map(world_size):
    """_67 (``problems = None``), _68 (``or`` → ``and``: 1000 and 128 each break one condition),
    _72 (message dropped)."""
    assert _refusal(world_size=world_size) == \
        f"world_size must be a multiple of 16 and >= local_map_size, got {world_size}"


def test_count_messages():
    """_75, _78 (messages dropped)."""
    assert _refusal(num_robots=0) == "num_robots must be >= 1, got 0"
    assert _refusal(num_features=-1) == "num_features must be >= 0, got -1"


@pytest.mark.parametrize("field", ["sigma_range_m", "peak_range"])
def test_range_bounds(field):
    """_81 (``1 < lo``), _82 / _88 (``0 <= lo``), _83 / _89 (``lo < hi``), _84 / _90 (message dropped):
    lo must be > 0 (0.5 is fine, 0 is not) and lo == hi is allowed."""
    assert getattr(SimParams(**{field: (0.5, 0.7)}), field) == (0.5, 0.7)
    assert getattr(SimParams(**{field: (2.0, 2.0)}), field) == (2.0, 2.0)
    for bad in [(0.0, 1.0), (-1.0, 1.0), (2.0, 1.0)]:
        assert _refusal(**{field: bad}) == f"{field} must satisfy 0 < lo <= hi, got {bad}"


@pytest.mark.parametrize("field", ["comm_radius_m", "max_speed_mps", "dt_s", "truncation_sigmas"])
@pytest.mark.parametrize("value", [0, -1.5])
def test_positive_floats(field, value):
    """_102, _132 (``> 0`` → ``>= 0``), _104.._108, _134.._138 (message dropped / the value's
    ``getattr`` broken)."""
    assert _refusal(**{field: value}) == f"{field} must be > 0, got {value}"


@pytest.mark.parametrize("field", ["obs_size", "history_size"])
def test_positive_sizes(field):
    """_132, _134.._138 for the int sizes."""
    assert _refusal(**{field: 0}) == f"{field} must be > 0, got 0"


@pytest.mark.parametrize("kw", [dict(local_map_size=264), dict(sensor_size=63)])
def test_local_map_multiple_of_16_and_sensor_even(kw):
    """_109 (``or`` → ``and``: each condition alone is refused), _114.._116 (message changed)."""
    assert _refusal(**kw) == "local_map_size must be a multiple of 16 and sensor_size even"


def test_all_problems_are_reported_joined_by_semicolons():
    """_139.._141 (the joined message dropped / misspelt)."""
    assert _refusal(world_size=1000, num_robots=0, dt_s=0) == (
        "world_size must be a multiple of 16 and >= local_map_size, got 1000; "
        "num_robots must be >= 1, got 0; dt_s must be > 0, got 0")


def test_env_bytes_formula():
    """env_bytes_2.._13: every robot's float32 map padded by the local map on each axis
    (4 N (W + L)²), the world map and its float64 prefix sums (48 W²) and the features (32 F)."""
    p = SimParams(world_size=48, local_map_size=16, sensor_size=8, num_robots=3, num_features=5)
    assert p.env_bytes() == 4 * 3 * 64 * 64 + 48 * 48 * 48 + 32 * 5 == 159904
    assert type(p.env_bytes()) is int


def test_check_fits_boundary_and_message(monkeypatch):
    """check_fits_4 (``>`` → ``>=``: exactly enough memory fits), _5 (message dropped), _6.._13
    (the GiB figures miscomputed)."""
    p = SimParams(num_robots=1000)
    need = p.env_bytes()
    assert need == 4 * 1000 * 1280**2 + 48 * 1024**2 + 32 * 32 == 6_603_932_672  # 6.15 GiB
    monkeypatch.setattr(params_mod, "physical_memory_bytes", lambda: need)
    p.check_fits("--num-robots")  # exactly enough
    monkeypatch.setattr(params_mod, "physical_memory_bytes", lambda: None)
    p.check_fits("--num-robots")  # the OS does not say: nothing refused
    monkeypatch.setattr(params_mod, "physical_memory_bytes", lambda: 3 * 2**30)
    with pytest.raises(ValueError) as e:
        p.check_fits("--num-robots")
    assert str(e.value) == ("--num-robots: N = 1000 robots and F = 32 features on a 1024 m world need at least "
                            "6.2 GiB for one environment, more than this machine's 3.0 GiB")


KNOWN = ("['check_oscillations', 'comm_radius_m', 'dt_s', 'history_size', 'local_map_size', 'max_speed_mps', "
         "'num_features', 'num_robots', 'obs_size', 'peak_range', 'sensor_size', 'sigma_range_m', "
         "'truncation_sigmas', 'world_size']")


def test_unknown_parameter_message():
    """The exact message, also as a scenario file shows it. Guards SimParams.from_dict__mutmut_3
    (no check: a TypeError from the constructor), _7 (message None) and _8 (the known names
    replaced by ``sorted(None)``)."""
    with pytest.raises(ValueError) as e:
        SimParams.from_dict({"comm_radius_mm": 3, "world_size": 256})
    assert str(e.value) == f"unknown parameter(s) ['comm_radius_mm']; expected some of {KNOWN}"
    with pytest.raises(ScenarioError) as e:
        Scenario.from_dict({"features": [{"mean": [1, 2], "sigma": 40, "peak": 1}], "robots": [[1, 2]],
                            "params": {"comm_radius_mm": 3}}, "s.json")
    assert str(e.value) == f"s.json: field 'params': unknown parameter(s) ['comm_radius_mm']; expected some of {KNOWN}"
