"""The controller registry (``madp.controllers``): one list of names, and everything else derived from it."""

from __future__ import annotations

import pytest

from madp.controllers import (BASELINES, CLASSICAL, CONTROLLERS, DEFAULT, LEARNED, NAMES, SAMPLING, checkpoint_kind,
                              make_controller)
from madp.errors import SettingError
from madp.sim import ClairvoyantCVT, DecentralizedCVT


def test_the_registry_is_the_one_list_of_names():
    from madp.eval.paper import PAPER_CONTROLLERS
    from madp.eval.stats import order_controllers
    from madp.eval.runner import EvalConfig

    assert NAMES == ("clairvoyant", "dcvt", "lpac", "madp", "madp_central")
    assert CLASSICAL == ("clairvoyant", "dcvt") and LEARNED == ("lpac", "madp", "madp_central")
    assert DEFAULT == ("clairvoyant", "dcvt", "lpac", "madp")  # madp eval without --controllers
    assert EvalConfig(suite="uniform").controllers == NAMES
    assert order_controllers(["zeta", *reversed(NAMES)]) == [*NAMES, "zeta"]
    assert PAPER_CONTROLLERS == ("dcvt", "lpac", "madp")
    assert BASELINES == ("dcvt", "lpac") and SAMPLING == ("madp", "madp_central")
    assert [checkpoint_kind(n) for n in NAMES] == [None, None, "lpac", "madp", "madp"]
    assert len({c.color for c in CONTROLLERS.values()}) == len(NAMES)  # a plot tells them apart


def test_settings_are_the_sampler_settings_of_a_controller_that_samples():
    from madp.policies import SamplingSettings

    s = SamplingSettings("ddim", 7, 0.5, True, select="oracle_cell", candidates=4)
    assert CONTROLLERS["madp_central"].settings(s) == {"sampler": "ddim", "sampling_steps": 7, "eta": 0.5,
                                                       "fixed_noise": True, "frame": "d4", "select": "oracle_cell",
                                                       "candidates": 4, "precision": "fp32"}
    assert CONTROLLERS["lpac"].settings(s) == {} and CONTROLLERS["dcvt"].settings(s) == {}


def test_make_controller_builds_each_kind():
    assert isinstance(make_controller("clairvoyant"), ClairvoyantCVT)
    assert isinstance(make_controller("dcvt"), DecentralizedCVT)
    with pytest.raises(SettingError, match=r"^controller: expected one of clairvoyant, dcvt, lpac, madp, madp_central, "
                                           r"got 'lqr'$") as e:
        make_controller("lqr")
    assert e.value.setting == "controller"
