"""``madp swarm``: one robot process per robot over Zenoh, driven by the world process.

A lockstep swarm ends where the one-process reference (``madp rollout --controller madp --runtime onnx``:
:class:`madp.export.swarm.OnnxMADPPolicy` with each robot's own noise) ends, over an ideal and over a
lossy, noisy network; its log reads back with rosbags; a robot process's commands are a function of
what it received alone; a killed robot becomes a failed robot and the run goes on; a killed world
leaves no robot process; real time counts missed deadlines and does not apply late commands; a user's
mistake is one line before any process starts."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from madp.export.swarm import OnnxMADPPolicy, exported
from madp.policies import SamplingSettings, shipped_checkpoint
from madp.robot import wire
from madp.sim import CoverageEnv, Scenario, rollout
from madp.sim.network import Message, NetworkSettings
from madp.swarm import run_swarm
from tests.robot.test_ros2 import madp_metadata, read_bag
from tests.swarm.swarm_testutils import (STEPS, Tap, children, kill_quietly, proc_alive, replay, scenario,
                                         wait_until)

LOSSY = NetworkSettings(loss=0.3, max_age_steps=2, position_noise_m=2.0, seed=1)


@pytest.fixture(scope="module")
def export_dir():
    """The shipped policy exported at the evaluation default, as ``madp rollout --runtime onnx`` exports it."""
    return exported(shipped_checkpoint("madp"), SamplingSettings())


@pytest.fixture(scope="module")
def lockstep(tmp_path_factory, export_dir):
    """A lockstep swarm run of :func:`scenario`, with robot 0's records tapped."""
    root = tmp_path_factory.mktemp("swarm")
    sc_path = root / "sc.json"
    scenario().save(sc_path)
    with pytest.MonkeyPatch.context() as mp:
        tap = Tap(mp, robot=0)
        summary = run_swarm(sc_path, export_dir, STEPS, root / "out", progress=False)
    return {"summary": summary, "out": root / "out", "tap": tap, "scenario": sc_path}


def _reference(sc: Scenario, network: NetworkSettings | None, steps: int) -> np.ndarray:
    """J(t)/J(0) of ``madp rollout --controller madp --runtime onnx`` (its controller, in this process)."""
    ctrl = OnnxMADPPolicy(shipped_checkpoint("madp"), SamplingSettings(), seed=sc.seed or 0, noise="robot")
    return rollout(CoverageEnv(sc, network=network), ctrl, steps).normalized_cost


def test_lockstep_swarm_equals_the_one_process_reference(lockstep):
    s = lockstep["summary"]
    ref = _reference(scenario(), None, STEPS)
    assert len(s["cost"]) == STEPS + 1 and np.abs(np.array(s["cost"]) - ref).max() <= 1e-6
    assert s["final_cost"] == s["cost"][-1] < 1.0 and s["mode"] == "lockstep" and s["failed"] == []
    on_disk = json.loads((lockstep["out"] / "summary.json").read_text())
    assert on_disk["cost"] == s["cost"] and sorted(p.name for p in lockstep["out"].iterdir()) == ["madp-swarm.json", "summary.json", "swarm.mcap"]
    assert s["outcome"] == "completed" and s["dropped"] == {"forged": 0, "malformed": 0, "foreign": 0}
    for r in s["robots"]:
        assert r["deadline_misses"] == 0 and r["failed_at_step"] is None and r["exit"] == "exit status 0"
        assert r["latency_ms"]["count"] == STEPS and 0 < r["latency_ms"]["p50"] <= r["latency_ms"]["p99"]
        assert r["messages"]["position"]["sent"] == r["messages"]["token"]["sent"] == STEPS
        assert r["messages"]["token"]["sent_bytes"] == STEPS * len(wire.encode_send(1, Message(0, 0, np.zeros(2), np.zeros(34))))
        assert r["messages"]["step"]["count"] == STEPS and isinstance(r["pid"], int)
    heard = sum(r["messages"]["token"]["delivered"] for r in s["robots"])
    assert heard == s["messages"]["token"]["delivered"] > 0


def test_lockstep_swarm_over_a_lossy_noisy_network_equals_the_reference(tmp_path, export_dir):
    sc = scenario(3)
    sc.save(tmp_path / "sc.json")
    s = run_swarm(tmp_path / "sc.json", export_dir, 12, tmp_path / "out", network=LOSSY, progress=False)
    assert np.abs(np.array(s["cost"]) - _reference(sc, LOSSY, 12)).max() <= 1e-6
    assert 0 < s["messages"]["position"]["delivered"] < 12 * 4 * 3  # the network lost some


def test_swarm_log_reads_back_with_rosbags(lockstep):
    topics, msgs, qos = read_bag(lockstep["out"] / "swarm.mcap")
    n = 4
    for i in range(n):
        assert topics[f"/robot_{i}/cmd_vel"] == "geometry_msgs/msg/TwistStamped"
        assert len([m for t, _, m in msgs if t == f"/robot_{i}/pose"]) == STEPS + 1
        assert len([m for t, _, m in msgs if t == f"/robot_{i}/madp_token"]) == STEPS
    cmd = [m for t, _, m in msgs if t == "/robot_0/cmd_vel"]
    tapped = lockstep["tap"].commands
    assert [[m.twist.linear.x, m.twist.linear.y] for m in cmd] == [tapped[k].tolist() for k in range(STEPS)]
    assert {m.header.frame_id for m in cmd} == {"world"}
    assert qos["/robot_2/madp_token"][0].name == "BEST_EFFORT"
    meta = madp_metadata(lockstep["out"] / "swarm.mcap")
    assert Scenario.from_dict(json.loads(meta["scenario"])).to_dict() == scenario().to_dict()
    assert (meta["steps"], meta["seed"], meta["controller"]) == (str(STEPS), "7", "madp")


def _noise(seed: int, num_robots: int):
    """Records for the other robots' keys, different with every seed: their step packets (other
    positions, other maps) and deliveries of messages robot 0's radio did not deliver to it."""
    rng = np.random.default_rng(seed)

    def records(n: int):
        out = []
        for j in range(1, num_robots):
            pos = rng.uniform(0, 512, 2)
            out.append((j, "step", wire.encode_step(j, n, pos, pos.astype(int) - 32, rng.random((64, 64), np.float32))))
            msgs = [Message(int(k), n, rng.uniform(0, 512, 2), rng.standard_normal(34).astype(np.float32))
                    for k in rng.permutation(num_robots)[:2]]
            out.append((j, "tokens", wire.encode_delivery(wire.PHASE_TOKEN, j, n, msgs)))
        return out

    return records


def test_a_robot_process_acts_on_what_it_received_alone(lockstep, export_dir):
    """Robot 0's recorded inputs replayed to a fresh robot 0 process twice, while the rest of the world
    (the other robots' step packets: their positions and maps; messages robot 0's radio did not
    deliver) is made up anew each time: the same commands, bit for bit, as in the swarm. Without the
    stop packet, a robot whose world falls silent exits (status 3)."""
    inputs = lockstep["tap"].inputs
    assert inputs[-1][0] == "step" and wire.decode(inputs[-1][1]).stop
    first, proc = replay(export_dir, inputs, 0, 4, _noise(1, 4))
    assert proc.wait(timeout=20) == 0
    kill_quietly(proc)
    second, proc = replay(export_dir, inputs[:-1], 0, 4, _noise(2, 4), silence_s=2.0)
    try:
        assert proc.wait(timeout=20) == 3
    finally:
        kill_quietly(proc)
    recorded = lockstep["tap"].commands
    assert sorted(first) == sorted(second) == list(range(STEPS))
    for k in range(STEPS):
        assert np.array_equal(first[k], recorded[k]) and np.array_equal(second[k], recorded[k])


def test_killing_the_world_leaves_no_robot_process(tmp_path, export_dir):
    scenario().save(tmp_path / "sc.json")
    world = subprocess.Popen([sys.executable, "-m", "madp.cli", "swarm", "--scenario", str(tmp_path / "sc.json"),
                              "--policy", str(export_dir), "--steps", "100000", "--rate-hz", "5", "--out",
                              str(tmp_path / "out")], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert "robot processes connected" in world.stdout.readline()  # the steps have begun
        robots = children(world.pid)
        assert len(robots) == 4
    finally:
        world.send_signal(signal.SIGKILL)
        world.wait()
    assert wait_until(lambda: not any(proc_alive(p) for p in robots), 5.0), [p for p in robots if proc_alive(p)]


def test_real_time_with_a_robot_process_killed_mid_run(tmp_path, export_dir, monkeypatch):
    """At 2 Hz, robot 2's process SIGKILLed before step 4: the run goes on to its end, the summary names
    the robot and the step, its commands stop; every robot's latencies and deadline misses are counted
    (the stand-in robots of tests/swarm/test_world.py check the deadlines' rules themselves)."""
    import madp.swarm.world as world

    step = world.World.step

    def killing_step(self, k):
        if k == 4:
            os.kill(self.robots.pids[2], signal.SIGKILL)
        return step(self, k)

    monkeypatch.setattr(world.World, "step", killing_step)
    scenario().save(tmp_path / "sc.json")
    s = run_swarm(tmp_path / "sc.json", export_dir, 8, tmp_path / "out", rate_hz=2.0, progress=False)
    assert s["mode"] == "real time" and s["deadlines"] == {"beacon": 0.25, "token": 0.6, "command": 1.0, "period_ms": 500.0}
    assert [(f["robot"], f["step"]) for f in s["failed"]] == [(2, 4)] and "SIGKILL" in s["failed"][0]["why"]
    r = s["robots"][2]
    assert r["failed_at_step"] == 4 and r["exit"] == "killed by SIGKILL" and r["messages"]["step"]["count"] in (4, 5)
    assert all(s["robots"][i]["exit"] == "exit status 0" and s["robots"][i]["failed_at_step"] is None for i in (0, 1, 3))
    assert len(s["cost"]) == 9 and all(np.isfinite(s["cost"])) and s["wall_s"] >= 7 * 0.5
    for r in s["robots"]:
        assert r["latency_ms"]["count"] >= 1 and r["latency_ms"]["p99"] >= r["latency_ms"]["p50"] > 0
        assert 0 <= r["deadline_misses"] <= 8 and sum(r["misses_by_phase"].values()) >= r["deadline_misses"]
    _, msgs, _ = read_bag(tmp_path / "out" / "swarm.mcap")
    assert len([m for t, _, m in msgs if t == "/robot_2/cmd_vel"]) == 4  # none applied once it failed


@pytest.mark.parametrize("args,needle", [
    (["--scenario", "{tmp}/none.json"], "none.json"),
    (["--policy", "{tmp}"], "runtime.json"),
    (["--rate-hz", "0"], "--rate-hz"),
    (["--rate-hz", "1e-9"], "--rate-hz"),
    (["--rate-hz", "1e6"], "--rate-hz"),
    (["--steps", "100000000000"], "--steps"),
    (["--network", "loss=2"], "loss"),
    (["--steps", "0"], "--steps"),
    (["--out", "{tmp}/sc.json"], "not a directory"),
    (["--out", "{tmp}"], "not empty"),
])
def test_user_errors_are_one_line_before_any_process_starts(tmp_path, export_dir, monkeypatch, args, needle):
    from madp.swarm import robots
    from tests.test_reliability_errors import assert_one_line, cli

    def refuse(*a, **k):
        raise AssertionError("a robot process was started")

    monkeypatch.setattr(robots.RobotProcesses, "__init__", refuse)
    scenario().save(tmp_path / "sc.json")
    base = {"--scenario": str(tmp_path / "sc.json"), "--policy": str(export_dir), "--steps": "3",
            "--out": str(tmp_path / "out")}
    extra = [a.format(tmp=tmp_path) for a in args]
    for flag, value in zip(extra[::2], extra[1::2]):
        base[flag] = value
    assert_one_line(*cli("swarm", *[x for kv in base.items() for x in kv]), needle)
    assert not (tmp_path / "out").exists()


def test_overwrite_replaces_only_what_a_recorded_run_wrote_and_the_machine_is_checked(tmp_path, export_dir,
                                                                                      monkeypatch):
    """A folder that holds only the user's own summary.json is not a swarm run's: --overwrite refuses,
    naming it, and leaves it; more robots than the machine's memory holds is one line, before any
    robot process starts."""
    from madp.swarm import robots
    from tests.test_reliability_errors import assert_one_line, cli

    def refuse(*a, **k):
        raise AssertionError("a robot process was started")

    monkeypatch.setattr(robots.RobotProcesses, "__init__", refuse)
    scenario().save(tmp_path / "sc.json")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "summary.json").write_text("my own notes")
    args = ["swarm", "--scenario", tmp_path / "sc.json", "--policy", export_dir, "--steps", "3", "--out", tmp_path / "out"]
    assert_one_line(*cli(*args, "--overwrite"), "summary.json", "not written by madp")
    assert (tmp_path / "out" / "summary.json").read_text() == "my own notes"
    from madp.swarm.run import OWNED, RECORD, _check_out

    prev = tmp_path / "prev"  # an earlier run, by its record: replaced
    prev.mkdir()
    for name in OWNED:
        (prev / name).write_text(json.dumps({"files": list(OWNED)}) if name == RECORD else "run")
    assert_one_line(*cli(*args[:-1], prev), "--overwrite replaces it")
    _check_out(prev, True)
    assert list(prev.iterdir()) == []
    monkeypatch.setattr(robots, "available_mb", lambda: 2 * robots.ROBOT_MB)
    assert_one_line(*cli(*args[:-1], tmp_path / "new"), "4 robot processes need", "at most 2 robots")
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("network", [None, LOSSY], ids=["ideal", "lossy"])
def test_a_joint_rule_runs_its_cost_round_and_equals_the_one_process_reference(tmp_path, network):
    """``value_joint`` (a map prior, random here): each robot sends its K costs in a fourth phase and
    keeps the copy of least summed cost over the neighbours it holds; the lockstep swarm ends where the
    one-process run ends, and elsewhere than the same rule robot by robot."""
    import torch

    from madp.models.map_prior import MapPrior
    from madp.training.map_prior import add_prior

    torch.manual_seed(1)
    policy = tmp_path / "policy.safetensors"
    add_prior(shipped_checkpoint("madp"), policy, MapPrior().eval(), {})
    joint = SamplingSettings.of(select="value_joint")
    sc = Scenario.random(7, scenario().params, launch=(150.0, 150.0, 330.0, 330.0))
    sc.save(tmp_path / "sc.json")
    s = run_swarm(tmp_path / "sc.json", exported(policy, joint), 10, tmp_path / "out", network=network, progress=False)

    def reference(sampling):
        ctrl = OnnxMADPPolicy(policy, sampling, seed=sc.seed, noise="robot")
        return rollout(CoverageEnv(sc, network=network), ctrl, 10).normalized_cost

    assert np.abs(np.array(s["cost"]) - reference(joint)).max() <= 1e-6
    assert np.abs(reference(SamplingSettings.of(select="value")) - reference(joint)).max() > 1e-4
    assert all(r["messages"]["cost"]["sent"] == 10 for r in s["robots"]) and s["messages"]["cost"]["delivered"] > 0
    assert all(set(r["misses_by_phase"]) == {"beacon", "token", "cost", "command"} for r in s["robots"])
