"""The scenario type's contract: what ``Scenario.random`` draws, the exact JSON ``to_dict``/``save``
write, the exact one-line errors of ``load``, ``from_dict`` and ``check_coverable`` (the CLI prints them
as they are, so the whole message is pinned), the world's closed bounds for robots, the memory refusal,
the optional fields kept, and the features' limits (σ and peak > 0, the mass 2πσ²·peak finite).

Written against the mutants mutmut left alive in ``madp/sim/scenario.py``; each test names
the mutants it kills (``from_dict`` mutants are written ``from_dict_N``). Tiny worlds (256 m) keep
every test cheap."""

from __future__ import annotations

import json
import locale
import sys

import numpy as np
import pytest

from madp.sim import Scenario, ScenarioError, SimParams
from madp.sim import params as params_mod
from madp.sim.idf import random_features
from madp.sim.scenario import check_coverable, _features


W = 256


#: One valid feature on the 256 m world, for documents whose features are not the point.
FEATURE = {"mean": [100.0, 120.0], "sigma": 40.0, "peak": 0.8}


def small(**kw) -> SimParams:
    return SimParams(**{"world_size": W, "num_robots": 1, "num_features": 1, **kw})


def test_random_draws_features_then_robots_from_the_seed():
    """The documented recipe, which makes every dataset reproducible from its seeds: one
    ``default_rng(seed)``; the features first; then robot x and robot y, each uniform in
    [1e-4, W - 1e-4]; the params, seed and an empty name kept. Guards random__mutmut_1 (default name
    "XXXX"), _5 (``default_rng(None)``: a fresh draw each call), _23/_24 (x or y drawn up to
    W + 1e-4) and _46 (params dropped: SimParams() defaults)."""
    p = SimParams(world_size=W, num_robots=5, num_features=3, comm_radius_m=100.0)
    sc = Scenario.random(7, p)
    rng = np.random.default_rng(7)
    feats = random_features(rng, 3, W, p.sigma_range_m, p.peak_range)
    x = rng.uniform(1e-4, W - 1e-4, 5)
    y = rng.uniform(1e-4, W - 1e-4, 5)
    np.testing.assert_array_equal(sc.features, feats)
    np.testing.assert_array_equal(sc.robots_m, np.column_stack([x, y]))
    assert sc.params == p and sc.seed == 7 and sc.name == "" and sc.source == ""
    again = Scenario.random(7, p)
    np.testing.assert_array_equal(again.robots_m, sc.robots_m)


def test_random_launch_rectangle_and_name():
    """``launch`` = (x0, y0, x1, y1) is where robots start, drawn after the features, and ``name`` is
    kept. Guards random__mutmut_20 (``launch`` ignored: the whole world) and _42/_47 (name None or
    dropped)."""
    p = SimParams(world_size=W, num_robots=40, num_features=2)
    sc = Scenario.random(3, p, launch=(10.0, 20.0, 30.0, 25.0), name="corner")
    assert sc.name == "corner"
    assert ((sc.robots_m[:, 0] >= 10) & (sc.robots_m[:, 0] <= 30)).all()
    assert ((sc.robots_m[:, 1] >= 20) & (sc.robots_m[:, 1] <= 25)).all()
    rng = np.random.default_rng(3)
    random_features(rng, 2, W, p.sigma_range_m, p.peak_range)
    np.testing.assert_array_equal(sc.robots_m[:, 0], rng.uniform(10.0, 30.0, 40))


def test_to_dict_writes_only_what_differs_from_the_defaults():
    """``params`` holds exactly the overrides (N and F follow the lists, so never), then name, source
    and seed when set. Guards to_dict__mutmut_2..9 (overrides None, or/==/in, the excluded names
    mangled so num_robots/num_features leak in), _31/_32/_33 (params value None or key renamed),
    _42.._46 (name/source written as None or through a broken getattr), _48.._51 (seed)."""
    sc = Scenario(np.array([[10.0, 20.0, 5.0, 0.5]]), np.array([[1.0, 2.0], [3.5, 4.0]]),
                  SimParams(world_size=W, num_robots=2, num_features=1, comm_radius_m=128.0),
                  name="n", seed=7, source="s")
    assert sc.to_dict() == {
        "features": [{"mean": [10.0, 20.0], "sigma": 5.0, "peak": 0.5}],
        "robots": [[1.0, 2.0], [3.5, 4.0]],
        "params": {"world_size": 256, "comm_radius_m": 128.0},
        "name": "n", "source": "s", "seed": 7,
    }
    plain = Scenario(sc.features, sc.robots_m, SimParams(num_robots=2, num_features=1), seed=0)
    assert plain.to_dict() == {"features": sc.to_dict()["features"], "robots": [[1.0, 2.0], [3.5, 4.0]],
                               "seed": 0}


SAVED = """{
 "features": [
  {
   "mean": [
    10.0,
    20.0
   ],
   "sigma": 5.0,
   "peak": 0.5
  }
 ],
 "robots": [
  [
   1.0,
   2.0
  ]
 ],
 "params": {
  "world_size": 256,
  "comm_radius_m": 128.0
 },
 "name": "n",
 "seed": 7
}
"""


def test_save_writes_the_pinned_layout(tmp_path):
    """A saved scenario file is byte-stable: one value per line, one-space indent, keys in the
    order features, robots, params, name, seed, and a final newline (so files written by
    ``madp scenario`` and the city importer diff line by line across versions). Guards
    save__mutmut_7/_9 (``indent=None``: one line) and _10 (``indent=2``)."""
    sc = Scenario(np.array([[10.0, 20.0, 5.0, 0.5]]), np.array([[1.0, 2.0]]), small(comm_radius_m=128.0),
                  name="n", seed=7)
    sc.save(tmp_path / "s.json")
    assert (tmp_path / "s.json").read_text(encoding="utf-8") == SAVED


def test_load_reads_utf8_whatever_the_locale(tmp_path):
    """Scenario files are UTF-8 JSON, also when the process runs in a C (ASCII) locale. Guards
    load__mutmut_4 (``read_text(encoding=None)``: the locale's encoding, here ASCII, so "Zürich"
    fails to decode). In Python's UTF-8 mode both read UTF-8 and the test cannot tell them apart."""
    p = tmp_path / "s.json"
    p.write_bytes(json.dumps({"features": [FEATURE], "robots": [[1, 2]], "params": {"world_size": W},
                              "name": "Zürich"}, ensure_ascii=False).encode("utf-8"))
    before = locale.setlocale(locale.LC_CTYPE)
    try:
        locale.setlocale(locale.LC_CTYPE, "C")
        if not sys.flags.utf8_mode:
            assert locale.getpreferredencoding(False) != "UTF-8"  # the test really runs non-UTF-8
        sc = Scenario.load(p)
    finally:
        locale.setlocale(locale.LC_CTYPE, before)
    assert sc.name == "Zürich"


def test_unreadable_file_message(tmp_path):
    """The exact message for a file that cannot be opened: the OS's reason, no errno, no repr.
    Guards load__mutmut_7 (message None) and _8 (``e.strerror and e``: "[Errno 2] ... 'path'")."""
    missing = tmp_path / "missing.json"
    with pytest.raises(ScenarioError) as e:
        Scenario.load(missing)
    assert str(e.value) == f"{missing}: cannot read scenario file (No such file or directory)"


@pytest.mark.parametrize("value,shown", [
    (float("inf"), "inf"),
    (float("nan"), "nan"),
    (10**400, "1" + "0" * 19 + "…"),  # beyond float range: the first 20 characters and an ellipsis
])
def test_non_finite_coordinate_message(value, shown):
    """``{field} must be a finite number, got {value}``, a huge integer cut to 20 characters plus
    "…". Guards _number__mutmut_9 (message None), _10 (``str(None)``), _11 (21 characters), _12/_13
    (ellipsis never / always), _14 ("XX…XX"), _17 ("XXXX" after short values)."""
    with pytest.raises(ScenarioError) as e:
        Scenario.from_dict({"features": [FEATURE], "robots": [[1.0, 2.0], [value, 3.0]]}, "s.json")
    assert str(e.value) == f"s.json: field 'robots[1]' must be a finite number, got {shown}"


S = 2.0**-10  # a σ far below a cell (exact in binary, so "exactly 2σ from the border" is exact)


R = 2 * S  # its reach at the default truncation of 2 σ


OUTSIDE = ("s.json: the importance map is 0 everywhere (every feature lies outside the world [0, 256]² "
           "(beyond {t} σ)), so J(0) = 0 and J(t)/J(0) is undefined")


TOO_SMALL = ("s.json: the importance map is 0 everywhere (its features' σ (smallest {s} m) or peaks are too "
             "small to give any cell importance), so J(0) = 0 and J(t)/J(0) is undefined")


def test_no_features_message():
    """Guards check_coverable__mutmut_4 (no error for an empty feature list) and _5/_6 (reason
    text changed)."""
    with pytest.raises(ScenarioError) as e:
        Scenario.from_dict({"features": [], "robots": [[1, 2]], "params": {"world_size": W}}, "s.json")
    assert str(e.value) == ("s.json: the importance map is 0 everywhere (it has no features), so J(0) = 0 "
                            "and J(t)/J(0) is undefined")


@pytest.mark.parametrize("feature,expected", [
    # wholly outside, one case per side (reach 20 m): the "outside" reason
    ((-25.0, 100.0, 10.0, 1.0), OUTSIDE),
    ((281.0, 100.0, 10.0, 1.0), OUTSIDE),
    ((100.0, -25.0, 10.0, 1.0), OUTSIDE),
    ((100.0, 281.0, 10.0, 1.0), OUTSIDE),
    # reach 1 m, 2 m outside; a σ- or peak-based reach of 4 m / 6 m would touch the world
    ((-2.0, 100.0, 0.5, 3.0), OUTSIDE),
    # inside the world, or on its border, but σ too small for any cell centre: the "too small" reason
    ((100.0, 100.0, S, 1.0), TOO_SMALL),
    ((0.0, 100.0, S, 1.0), TOO_SMALL),
    ((256.0, 100.0, S, 1.0), TOO_SMALL),
    ((100.0, 0.0, S, 1.0), TOO_SMALL),
    ((100.0, 256.0, S, 1.0), TOO_SMALL),
    # the 2σ disc just touches the border from outside: not "beyond 2 σ"
    ((-R, 100.0, S, 1.0), TOO_SMALL),
    ((256.0 + R, 100.0, S, 1.0), TOO_SMALL),
    ((100.0, -R, S, 1.0), TOO_SMALL),
    ((100.0, 256.0 + R, S, 1.0), TOO_SMALL),
])
def test_zero_map_reason(feature, expected):
    """A feature that gives no cell importance is refused with the right reason: "outside the world
    (beyond t σ)" iff its t·σ disc lies strictly outside [0, W]² on some side, else "σ too small"
    (naming the smallest σ, not the peak). One case per side and per edge of each comparison.
    Guards check_coverable__mutmut_14..37 (reach None, t/σ, t·peak; ``outside`` None; & for |; the
    wrong column or sign; < vs <=, 0 vs 1, > vs >=; ``why`` None; the reason forced either way),
    _38 (the peak's minimum printed as σ) and _39 (message None)."""
    x, y, sigma, peak = feature
    with pytest.raises(ScenarioError) as e:
        check_coverable(np.array([feature]), small(), "s.json")
    assert str(e.value) == expected.format(t=2, s=f"{sigma:.3g}")


def test_zero_map_uses_the_scenarios_truncation():
    """The map is tested with the scenario's ``truncation_sigmas``: a feature 15 m outside the world
    with σ = 10 m reaches cells at 2σ but not at 1σ, so with t = 1 it is refused ("beyond 1 σ"),
    with t = 2 accepted. Guards check_coverable__mutmut_13 (the default truncation of 2 used)."""
    feature = np.array([[-15.0, 128.0, 10.0, 1.0]])
    with pytest.raises(ScenarioError) as e:
        check_coverable(feature, small(truncation_sigmas=1.0), "s.json")
    assert str(e.value) == OUTSIDE.format(t=1)
    check_coverable(feature, small(truncation_sigmas=2.0), "s.json")


# --- Scenario.from_dict ---------------------------------------------------------------------------

def doc(**kw) -> dict:
    return {"features": [FEATURE], "robots": [[10.0, 20.0]], "params": {"world_size": W}, **kw}


def refusal(d, *where) -> str:
    with pytest.raises(ScenarioError) as e:
        Scenario.from_dict(d, *where)
    return str(e.value)


def test_default_where_is_scenario():
    """from_dict_1 / _2 (the default place misspelt) and from_dict_44 (message dropped)."""
    assert refusal(doc(robots=[])) == "scenario: field 'robots' must list at least one [x, y]"
    assert refusal(doc(robots=[]), "s.json") == "s.json: field 'robots' must list at least one [x, y]"


@pytest.mark.parametrize("xy", [[0.0, 0.0], [0.5, 0.25], [W, W], [0.0, W]])
def test_robots_on_the_closed_world_are_accepted(xy):
    """from_dict_67 (``> 0``), _68 (``>= 1``), _69 (``< w``): the world is [0, W] inclusive."""
    sc = Scenario.from_dict(doc(robots=[xy]))
    assert sc.robots_m.tolist() == [xy]


@pytest.mark.parametrize("xy,i", [([-0.001, 3.0], 0), ([3.0, W + 0.001], 0)])
def test_robots_just_outside_are_refused(xy, i):
    assert refusal(doc(robots=[xy])) == f"scenario: field 'robots[{i}]' = {xy} is outside the world [0, {W}]"


def test_memory_refusal_names_the_file(monkeypatch):
    """from_dict_85 (``check_fits(None)``), _86 / _87 (the message dropped)."""
    monkeypatch.setattr(params_mod, "physical_memory_bytes", lambda: 2**20)
    assert refusal(doc(), "s.json") == (
        "s.json: N = 1 robots and F = 1 features on a 256 m world need at least 0.0 GiB for one "
        "environment, more than this machine's 0.0 GiB")


def test_optional_fields_are_kept_and_default_empty():
    """from_dict_98 / _104 (seed dropped), _99 / _105 / _114.._121 (source dropped or read from the
    wrong key), _108 / _110 / _113 (the absent name's default: ``"None"`` / ``"XXXX"``)."""
    sc = Scenario.from_dict(doc(name="city", seed=5, source="osm"))
    assert (sc.name, sc.seed, sc.source) == ("city", 5, "osm")
    sc = Scenario.from_dict(doc())
    assert (sc.name, sc.seed, sc.source) == ("", None, "")


def test_feature_is_stored_as_x_y_sigma_peak():
    """_features_63 (``mean[1]`` for x)."""
    assert Scenario.from_dict(doc()).features.tolist() == [[100.0, 120.0, 40.0, 0.8]]


def test_feature_mean_errors_name_the_feature():
    """_features_27 (the name passed to ``_points`` dropped)."""
    bad = {**FEATURE, "mean": [1.0, 2.0, 3.0]}
    assert refusal(doc(features=[FEATURE, bad])) == \
        "scenario: field 'features[1].mean[0]' must be [x, y], got [1.0, 2.0, 3.0]"


@pytest.mark.parametrize("sigma,peak", [(0, 0.8), (40.0, 0), (-1.0, 0.8)])
def test_sigma_and_peak_must_be_positive(sigma, peak):
    """_features_49 (``sigma < 0``), _51 (``peak < 0``)."""
    f = {**FEATURE, "sigma": sigma, "peak": peak}
    assert refusal(doc(features=[f])) == \
        f"scenario: field 'features[0]': sigma and peak must be > 0, got sigma={float(sigma)}, peak={float(peak)}"


def test_small_sigma_is_accepted():
    """_features_50 (``sigma <= 1`` refused)."""
    assert _features([{**FEATURE, "sigma": 0.5}], "w")[0].tolist() == [100.0, 120.0, 0.5, 0.8]


@pytest.mark.parametrize("sigma,peak,overflows", [
    (1e150, 1e10, True),    # _56 (σ²/peak): 2π·1e300·1e10 overflows, 2π·1e300/1e10 does not
    (1e200, 1.0, True),     # _57 (σ/σ·peak)
    (1e154, 1.0, True),     # _59 (2/π): 2π·1e308 overflows, (2/π)·1e308 does not
    (5e153, 1.0, False),    # _60 (3π): 2π·2.5e307 ≈ 1.6e308 is finite, 3π·2.5e307 is not
])
def test_mass_overflow_boundary(sigma, peak, overflows):
    """_features_56, _57, _59, _60 (the mass computed otherwise), _61 (message dropped)."""
    f = [{**FEATURE, "sigma": sigma, "peak": peak}]
    if overflows:
        with pytest.raises(ScenarioError) as e:
            _features(f, "w")
        assert str(e.value) == \
            "w: field 'features[0]': sigma and peak are too large (the feature's mass 2πσ²·peak overflows)"
    else:
        assert _features(f, "w")[0].tolist() == [100.0, 120.0, sigma, peak]


def test_with_params_changes_only_the_named_parameters():
    """Guards ``Scenario.with_params``: a copy whose params differ only where asked, with the same
    features and robots, the original untouched (mutants: ``replace(None, …)``, ``params=None``,
    ``replace(**changes)``, changes dropped)."""
    s = Scenario.from_dict(doc())
    t = s.with_params(comm_radius_m=100.0)
    assert t.params.comm_radius_m == 100.0 and s.params.comm_radius_m != 100.0
    assert t.params.world_size == s.params.world_size == W
    np.testing.assert_array_equal(t.features, s.features)
    np.testing.assert_array_equal(t.robots_m, s.robots_m)
