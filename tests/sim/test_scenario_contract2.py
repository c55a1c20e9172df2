"""``Scenario.from_dict``'s contract, second part: the default place named in errors, the world's
closed bounds for robots, the memory refusal, the optional fields kept, and the features' limits
(σ and peak > 0, the mass 2πσ²·peak finite).

Written against the second batch of mutants mutmut left alive in ``madp/sim/scenario.py``; each
test names the mutants it kills (``from_dict`` mutants are written ``from_dict_N``). The messages
are printed by the CLI as they are, so they are pinned whole.
"""

from __future__ import annotations

import numpy as np
import pytest

from madp.sim import Scenario, ScenarioError
from madp.sim import params as params_mod
from madp.sim.scenario import _features

W = 256
FEATURE = {"mean": [100.0, 120.0], "sigma": 40.0, "peak": 0.8}


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
