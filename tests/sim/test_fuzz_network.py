"""``NetworkSettings.parse`` on any text: a NetworkSettings or a one-line SettingError of setting
``network``, never another exception (``madp rollout --network``, ``madp swarm --network``)."""

from __future__ import annotations

from dataclasses import fields

from hypothesis import strategies as st

from madp.errors import SettingError
from madp.sim.network import NetworkSettings
from tests.fuzzing import SCALARS, twins

NAMES = [f.name for f in fields(NetworkSettings)]
#: NAME=VALUE items: known and unknown names, hostile values, missing or doubled '=' signs.
ITEMS = st.builds(lambda name, eq, value: f"{name}{eq}{value}",
                  st.sampled_from(NAMES) | st.text(max_size=8), st.sampled_from(["=", "", "==", " = "]),
                  SCALARS.map(str) | st.text(max_size=8))
TEXTS = st.text(max_size=60) | st.lists(ITEMS, max_size=6).map(",".join) | st.lists(ITEMS, max_size=4).map(", ,".join)


def _parse_is_settings_or_one_line_error(text):
    try:
        s = NetworkSettings.parse(text)
    except SettingError as e:
        assert e.setting == "network" and str(e).startswith("network: ") and "\n" not in str(e)
        return
    assert isinstance(s, NetworkSettings)
    assert NetworkSettings(**s.as_dict()) == s  # a valid settings object


test_fuzz_parse, test_fuzz_parse_soak = twins(_parse_is_settings_or_one_line_error, 300, 5000, text=TEXTS)
