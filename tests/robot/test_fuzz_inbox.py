"""A robot must not stop over a bad packet: any inbox of good and malformed messages (NaN or infinite
fields, wrong token sizes, duplicated senders, steps from the future, stale steps, garbage objects)
gives an action, and every bad message is counted under its reason."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from madp.robot import RobotRuntime
from madp.robot.choice import explore_prior, local_views
from madp.robot.inbox import MAX_SENDER, MAX_STEP, read_inbox
from madp.sim import CoverageEnv, Scenario, SimParams
from madp.sim.network import Message
from tests.fuzzing import twins
from tests.robot.robot_testutils import export_tiny

STEP = 5
KINDS = ("good", "nan_position", "inf_token", "short_token", "no_token", "future", "stale", "duplicate", "self",
         "garbage", "far")
REASON = {"nan_position": "non_finite", "inf_token": "non_finite", "short_token": "bad_token", "no_token": "bad_token",
          "future": "future", "stale": "stale", "duplicate": "duplicate", "self": "duplicate", "garbage": "malformed",
          "far": "out_of_range"}

_world: dict = {}


def world(tmp_path_factory) -> dict:
    if not _world:
        out = tmp_path_factory.mktemp("fuzz-export")
        export_tiny(out)
        env = CoverageEnv(Scenario.random(1, SimParams(num_robots=3, num_features=4), launch=(480, 480, 520, 520)))
        views = explore_prior(env, local_views(env))
        row = type(views)(*(getattr(views, k)[:1] for k in ("start_m", "offset_m", "weights", "origin_m",
                                                            "neighbours_m", "valid")))
        rt = RobotRuntime(out)
        _world.update(rt=rt, obs=env.observations()[0], pos=env.positions_m[0], view=row)
    return _world


def _message(kind: str, sender: int, pos: np.ndarray, token: np.ndarray, data) -> object:
    jitter = np.array(data.draw(st.tuples(st.floats(-50, 50), st.floats(-50, 50))))
    p = pos + jitter
    if kind == "nan_position":
        p = np.array([data.draw(st.sampled_from([np.nan, np.inf, -np.inf])), p[1]])
    if kind == "far":
        p = pos + 400.0
    tok = token.copy()
    if kind == "inf_token":
        tok[data.draw(st.integers(0, len(tok) - 1))] = data.draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    if kind == "short_token":
        tok = tok[:data.draw(st.integers(0, len(tok) - 1))]
    if kind == "garbage":
        return data.draw(st.sampled_from([None, "token", 3, {"sender": 1}, Message("x", STEP, p, tok),
                                          Message(sender, 1.5, p, tok), Message(sender, STEP, np.zeros(3), tok)]))
    step = STEP + 1 if kind == "future" else STEP - 3 if kind == "stale" else STEP
    return Message(0 if kind == "self" else sender, step, p, None if kind == "no_token" else tok)


def _inbox_never_stops_the_robot(tmp_path_factory, data):
    w = world(tmp_path_factory)
    rt = w["rt"]
    kinds = data.draw(st.lists(st.sampled_from(KINDS), max_size=12))
    token = np.asarray(data.draw(st.lists(st.floats(-3, 3, width=32), min_size=rt.token_dim, max_size=rt.token_dim)),
                       np.float32)
    inbox, expect = [], {r: 0 for r in set(REASON.values()) | {"accepted"}}
    for j, kind in enumerate(kinds):
        sender = 1 + j
        if kind == "duplicate":  # two different messages of one sender and step: neither can be trusted
            first = _message("good", sender, w["pos"], token, data)
            inbox += [first, Message(sender, STEP, first.position_m + 1.0, first.token)]
        else:
            inbox.append(_message(kind, sender, w["pos"], token, data))
        expect[REASON.get(kind, "accepted")] += 2 if kind == "duplicate" else 1
    res = rt.step(0, STEP, w["obs"], w["pos"], inbox, seed=3, view=w["view"])
    assert np.isfinite(res.action_mps).all() and res.action_mps.shape == (2,)
    got = res.counts.as_dict()
    assert got["received"] == len(inbox)
    assert {k: got[k] for k in expect} == expect
    assert got["dropped"] + got["accepted"] + got["out_of_range"] == len(inbox)


test_fuzz_inbox, test_fuzz_inbox_soak = twins(_inbox_never_stops_the_robot, 40, 500, data=st.data())



def test_the_newest_message_of_a_sender_is_kept():
    """Of one sender's messages the newest step's is kept (older ones count as duplicates); identical
    copies count once; different messages of the same newest step are all dropped."""
    tok = np.zeros(4, np.float32)
    pos = np.zeros(2)
    older, newer = Message(1, 5, pos + 1.0, tok), Message(1, 6, pos + 2.0, tok + 1)
    kept, counts = read_inbox([newer, older], 0, 6, pos, 4, 100.0, max_age=3)
    assert [k[0] for k in kept] == [1] and np.array_equal(kept[0][1], newer.position_m)
    assert (counts.accepted, counts.duplicate) == (1, 1)
    kept, counts = read_inbox([newer, Message(1, 6, pos + 2.0, tok + 1)], 0, 6, pos, 4, 100.0, max_age=3)
    assert (counts.accepted, counts.duplicate) == (1, 1)
    kept, counts = read_inbox([newer, older, Message(1, 6, pos + 3.0, tok)], 0, 6, pos, 4, 100.0, max_age=3)
    assert (kept, counts.accepted, counts.duplicate) == ([], 0, 3)


@given(sender=st.one_of(st.integers(-2**70, 2**70), st.floats(allow_nan=True, allow_subnormal=False), st.booleans(), st.text(max_size=3)),
       step=st.one_of(st.integers(-2**70, 2**70), st.floats(allow_nan=True, allow_subnormal=False)))
@settings(max_examples=200, deadline=None)
def test_any_sender_or_step_field_never_raises(sender, step):
    """Whatever a message's sender and step fields hold, reading the inbox never raises; only ids in
    [0, MAX_SENDER] and steps in [0, MAX_STEP] (whole numbers) pass as well-formed."""
    msg = Message(sender, step, np.zeros(2), np.zeros(4, np.float32))
    kept, counts = read_inbox([msg], 0, 2**62, np.zeros(2), 4, 100.0, max_age=None)
    good = (isinstance(sender, int) and not isinstance(sender, bool) and 0 < sender <= MAX_SENDER
            and isinstance(step, int) and 0 <= step <= MAX_STEP)
    assert counts.received == 1 and counts.accepted == int(good)
