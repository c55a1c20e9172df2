"""Logs back into data: a recorded run (the rosbag2 MCAP file of ``madp swarm`` or of
``madp rollout --record-format ros2``, which carries its scenario) becomes expert-relabelled samples
in the dataset format, so a run's log feeds the next training round (``madp dataset import``).

A log is replayed, not trusted: the scenario from its ``madp`` metadata is rebuilt, the commands the
world applied (``/robot_<i>/cmd_vel``) drive a :class:`madp.sim.CoverageEnv` step by step, and every
robot's replayed position must match its logged pose (``/robot_<i>/pose``) to within
:data:`POSE_TOLERANCE_M`: a log that does not replay is refused, naming the robot and the step. A
robot that failed during the run has no command from its failure on: the import keeps the steps
before the first failure, in which every robot ran. A log whose poses do not reach the step count its
metadata gives is refused; nothing is allocated by that count before the messages are read.
Every ``record_every``-th state (and the last) becomes a sample: the clairvoyant expert's action U0 at
that state (the label, as in relabelling datagen), the positions X and the observations O of the
robots' true state. Each log is one episode; the whole import goes to one split (``train`` by default:
train on it beside another dataset with ``madp train --data BASE --data IMPORTED``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from madp.data_schema import ActionStatsAccumulator, DataError, Episode, Manifest, SplitInfo, write_shard
from madp.data_schema.manifest import MANIFEST_FILENAME, SPLITS
from madp.io.checksum import sha256_file
from madp.errors import SettingError
from madp.io.atomic import write_text_atomic
from madp.io.lock import locked_dir
from madp.io.owned import clear_owned, foreign_files
from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario
from madp.sim.rollout import Hook, act_alone, run

from .episodes import EpisodeRecorder
from .plan import DatagenConfig

__all__ = ["POSE_TOLERANCE_M", "RunLog", "import_logs", "log_episode", "read_log"]

#: How far (m) a replayed position may be from the logged pose (the log stores float64 metres).
POSE_TOLERANCE_M = 1e-6
#: The import's own state: which logs made which shard (beside the manifest).
IMPORT_FILE = ".import.json"


@dataclass(frozen=True)
class RunLog:
    """What a run's log holds: its ``scenario``, ``dt_s``, the commands the world applied
    ``commands_mps [T, N, 2]`` (step t's in row t) and the poses ``positions_m [T + 1, N, 2]``."""

    path: Path
    scenario: Scenario
    dt_s: float
    commands_mps: np.ndarray
    positions_m: np.ndarray


def _topic_index(topic: str, name: str) -> int | None:
    """i of ``/robot_<i>/<name>``, else None."""
    parts = topic.strip("/").split("/")
    if len(parts) != 2 or parts[1] != name or not parts[0].startswith("robot_"):
        return None
    tail = parts[0][len("robot_"):]
    return int(tail) if tail.isdigit() else None


def read_log(path: str | Path) -> RunLog:
    """The run recorded in rosbag2 MCAP file ``path``. A missing, truncated or foreign file is a
    one-line :class:`DataError` naming it and what was expected."""
    from mcap.reader import make_reader
    from mcap_ros2.reader import read_ros2_messages

    path = Path(path)
    if not path.is_file():
        raise DataError.at(path, "no such log file (a rosbag2 MCAP file of madp swarm or madp rollout --record-format ros2)")
    try:
        with open(path, "rb") as f:
            meta = {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
        if "madp" not in meta or "scenario" not in meta["madp"]:
            raise DataError.at(path, "no 'madp' metadata with the scenario: not a log madp recorded")
        info = meta["madp"]
        scenario = Scenario.from_dict(json.loads(info["scenario"]), f"{path} (madp metadata)")
        dt_s = float(info["dt_s"])
        n, steps = len(scenario.robots_m), int(info["steps"])
        if steps < 2:
            raise DataError.at(path, f"a log of {steps} step(s); importing needs at least 2")
        found = {"cmd_vel": [], "pose": []}  # (t, i, x, y) as logged: memory as the file's, never as its metadata says
        for m in read_ros2_messages(str(path)):
            topic, msg = m.channel.topic, m.ros_msg
            i = _topic_index(topic, "cmd_vel")
            if i is not None and i < n:
                t = _step(msg.header.stamp, dt_s)
                if 0 <= t < steps:
                    found["cmd_vel"].append((t, i, msg.twist.linear.x, msg.twist.linear.y))
                continue
            i = _topic_index(topic, "pose")
            if i is not None and i < n:
                t = _step(msg.header.stamp, dt_s)
                if 0 <= t <= steps:
                    found["pose"].append((t, i, msg.pose.position.x, msg.pose.position.y))
    except DataError:
        raise
    except (json.JSONDecodeError, KeyError, ValueError, TypeError) as e:
        raise DataError.at(path, f"malformed madp metadata ({type(e).__name__}: {e})") from None
    except Exception as e:  # the MCAP readers' own errors for a truncated or foreign file
        raise DataError.corrupt(path, "rosbag2 MCAP", e) from None
    last = max((t for t, *_ in found["pose"]), default=-1)
    if last != steps:
        raise DataError.at(path, f"its madp metadata says {steps} steps, but its poses end at step {last} "
                           "(a damaged log, or a run that ended before its last step)")
    commands, poses = _table(found["cmd_vel"], steps, n), _table(found["pose"], steps + 1, n)
    missing = np.argwhere(np.isnan(poses).any(-1))
    if len(missing):
        t, i = (int(v) for v in missing[0])
        raise DataError.at(path, f"/robot_{i}/pose has no message for step {t} "
                           f"(a log of {steps} steps and {n} robots needs one per robot and step)")
    lived = _lived(commands)
    if lived < 2:
        t, i = (int(v) for v in np.argwhere(np.isnan(commands).any(-1))[0])
        raise DataError.at(path, f"/robot_{i}/cmd_vel has no message from step {t} (the robot failed there): "
                           "fewer than 2 steps in which every robot ran, nothing to import")
    commands, poses = commands[:lived], poses[:lived + 1]  # the steps every robot lived
    return RunLog(path, scenario, dt_s, commands, poses)


def _table(rows: list[tuple], steps: int, n: int) -> np.ndarray:
    """``[steps, n, 2]`` of the logged ``(t, i, x, y)`` rows; NaN where none was logged."""
    out = np.full((steps, n, 2), np.nan)
    if rows:
        a = np.array(rows, np.float64)
        out[a[:, 0].astype(np.int64), a[:, 1].astype(np.int64)] = a[:, 2:]
    return out


def _lived(commands_mps: np.ndarray) -> int:
    """The steps before the first one at which a robot has no command (it failed): every step when none."""
    gaps = np.flatnonzero(np.isnan(commands_mps).any((1, 2)))
    return int(gaps[0]) if len(gaps) else len(commands_mps)


def _step(stamp, dt_s: float) -> int:
    """The control step of a header stamp ``t · dt_s``."""
    return int(round((int(stamp.sec) + int(stamp.nanosec) * 1e-9) / dt_s))


class _Replay(Hook):
    """Before each step of a log's replay: every robot's replayed position against its logged pose."""

    def __init__(self, log: RunLog):
        self.log = log

    def actions(self, t, envs, actions, act_s):
        gap = np.abs(envs[0].positions_m - self.log.positions_m[t]).max(1)
        if gap.max() > POSE_TOLERANCE_M:
            i = int(gap.argmax())
            raise DataError.at(self.log.path, f"does not replay: robot {i} at step {t} is {gap[i]:.3g} m from its "
                               "logged pose (the scenario or the applied commands do not match the run)")
        return False


def log_episode(log: RunLog, episode_id: int, record_every: int = 5) -> Episode:
    """Replay ``log`` (its applied commands drive the world) and label every ``record_every``-th state
    and the last before the final command with the clairvoyant expert's action, as datagen records
    (:class:`madp.datagen.episodes.EpisodeRecorder`)."""
    steps = len(log.commands_mps)
    cfg = DatagenConfig(1, record_every=record_every, max_steps=steps - 1, params=log.scenario.params)
    env, expert = CoverageEnv(log.scenario), ClairvoyantCVT()
    recorder = EpisodeRecorder(expert, cfg, max_samples=steps, stops_when_converged=False)
    run([env], act_alone(expert), [_Replay(log), recorder], drive=lambda envs, u: log.commands_mps[envs[0].steps][None])
    return recorder.episode(episode_id, log.scenario.seed if log.scenario.seed is not None else 0, env.world_map_f32)


def import_logs(logs: list[str | Path], out: str | Path, fmt: str = "mcap", split: str = "train", record_every: int = 5,
                overwrite: bool = False) -> Manifest:
    """Write the samples of ``logs`` (one episode and one shard each, in the order given) as a dataset
    in ``out`` with its manifest. The directory is locked while it is written; a directory holding
    files madp did not write is refused, and one madp wrote is replaced only with ``overwrite``."""
    if fmt not in ("mcap", "parquet"):
        raise SettingError("format", f"expected mcap or parquet, got {fmt!r}")
    if split not in SPLITS:
        raise SettingError("split", f"expected one of {', '.join(SPLITS)}, got {split!r}")
    if record_every < 1:
        raise SettingError("record_every", f"expected a positive number of steps, got {record_every}")
    if not logs:
        raise SettingError("logs", "expected at least one log file")
    runs = [read_log(p) for p in logs]  # every log read and checked before anything is written
    n = len(runs[0].scenario.robots_m)
    for log in runs:
        if len(log.scenario.robots_m) != n:
            raise DataError.at(log.path, f"has {len(log.scenario.robots_m)} robots where {runs[0].path} has {n}; "
                               "import swarms of one size into one dataset")
    root = Path(out)
    with locked_dir(root):
        _prepare(root, overwrite)
        acc = ActionStatsAccumulator()
        infos = []
        for k, log in enumerate(runs):
            ep = log_episode(log, k, record_every)
            acc.add(ep.actions)
            rel = f"{split}/shard-{k:05d}.{fmt}"
            info = write_shard(root / rel, [ep], fmt)
            info.file = rel
            infos.append(info)
        params = {"imported_logs": [{"file": str(r.path), "sha256": sha256_file(r.path)} for r in runs],
                  "record_every": record_every, "params": runs[0].scenario.params.to_dict()}
        splits = {s: SplitInfo(infos if s == split else []) for s in SPLITS}
        manifest = Manifest(format=fmt, num_robots=n, params=params, splits=splits,
                            action_stats=acc.result() if split == "train" else None,
                            created_by="madp dataset import " + " ".join(str(p) for p in logs) + f" --split {split}")
        write_text_atomic(root / IMPORT_FILE, json.dumps({"shards": [i.file for i in infos]}) + "\n")
        manifest.save(root / MANIFEST_FILENAME)
    return manifest


def _owned(root: Path) -> list[str]:
    """What an earlier import wrote in ``root``: its manifest, its record and the shards it lists."""
    rec = root / IMPORT_FILE
    if not rec.is_file():
        return []
    try:
        shards = list(json.loads(rec.read_text())["shards"])
    except (ValueError, KeyError, TypeError):
        shards = []
    return [MANIFEST_FILENAME, IMPORT_FILE, *shards]


def _prepare(root: Path, overwrite: bool) -> None:
    owned = _owned(root)
    foreign = foreign_files(root, owned)
    if foreign:
        raise DataError.at(foreign[0], "not a file madp dataset import wrote; choose an empty --out directory")
    if owned and not overwrite:
        raise DataError.at(root, "already holds an imported dataset; pass --overwrite to replace it")
    clear_owned(root, owned)
