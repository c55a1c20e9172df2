"""What a sample and an episode are: one versioned, validated in-memory definition.

A *sample* is one swarm snapshot of N robots (SPEC §3):

========================  ==========================  =========  =====================================
field                     shape                       dtype      meaning / unit
========================  ==========================  =========  =====================================
``actions``   (U0)        ``[N, 2]``                  float32    expert velocity, m/s, (x east, y north)
``positions`` (X)         ``[N, 2]``                  float32    robot positions, m, world frame
``observations`` (O)      ``[N, 4, 32, 32]``          float16    per-robot maps, channels
                                                                 (local, comm_x, comm_y, obstacle)
``episode_id``            scalar                      int64      which rollout the sample comes from
``step``                  scalar                      int64      simulation step index (Δt = 0.2 s)
``scenario_seed``         scalar                      int64      seed that generated the scenario
========================  ==========================  =========  =====================================

N is fixed within a dataset (32 by default). Two containers carry samples in memory:

* :class:`Episode` — the writer's input: one rollout, ``T`` recorded steps, plus optional
  visualisation extras (the world importance map and the expert's Voronoi goals).
* :class:`SampleBatch` — the reader's output: samples stacked along a leading axis ``B``, each with
  its own ``episode_id``/``step``/``scenario_seed``.

Every check raises :class:`DataError` with a single-line message naming the file or field and what
was expected, so the command line can print it without a traceback.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Iterator, Optional, Sequence

import numpy as np

from madp.errors import MadpError

#: Version of the sample layout and of its encodings. Bump on any incompatible change.
SCHEMA_VERSION = 1

#: Default number of robots per sample (N).
DEFAULT_NUM_ROBOTS = 32
#: Observation channels per robot, in the Coverage Control Library's order (local map, neighbours'
#: x, neighbours' y, obstacle/boundary map): the one list of their names (:mod:`madp.sim.observations`
#: makes them).
OBS_CHANNELS = ("local", "comm_x", "comm_y", "obstacle")
#: Observation image side in pixels.
OBS_SIZE = 32
#: Per-robot observation shape ``[C, H, W]``.
OBS_SHAPE = (len(OBS_CHANNELS), OBS_SIZE, OBS_SIZE)

#: Storage dtypes (always little-endian on disk).
ACTIONS_DTYPE = np.dtype("<f4")
POSITIONS_DTYPE = np.dtype("<f4")
OBSERVATIONS_DTYPE = np.dtype("<f2")
WORLD_MAP_DTYPE = np.dtype("<f4")
GOALS_DTYPE = np.dtype("<f4")
INDEX_DTYPE = np.dtype("<i8")

#: Largest value accepted for ``episode_id``, ``step`` and ``scenario_seed`` (they are int64 on
#: disk in Parquet and uint64 in MCAP; both must hold them).
MAX_INDEX = 2**63 - 1


class DataError(MadpError):
    """A dataset file or in-memory array is not what the schema expects.

    The message is always one line: ``"<file or field>: <what was expected>[, got <what>]"``.
    Newlines in the message are collapsed so the CLI can print ``str(err)`` as is.
    """

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))

    @classmethod
    def at(cls, where: object, problem: str) -> "DataError":
        """Build an error for ``where`` (a path or a field name) with a ``problem`` description."""
        return cls(f"{where}: {problem}")

    @classmethod
    def corrupt(cls, path: object, fmt: str, err: BaseException) -> "DataError":
        """A shard of format ``fmt`` that its reader could not decode, with the reader's reason (shortened)."""
        detail = f"{type(err).__name__}: {err}"
        if len(detail) > 160:
            detail = detail[:157] + "..."
        return cls.at(path, f"corrupt or truncated {fmt} shard ({detail})")


# --------------------------------------------------------------------------------------------
# validation helpers


def sample_shapes(num_robots: int) -> dict[str, tuple[int, ...]]:
    """Per-sample array shapes for a dataset with ``num_robots`` robots (no leading axis)."""
    return {
        "actions": (num_robots, 2),
        "positions": (num_robots, 2),
        "observations": (num_robots, *OBS_SHAPE),
    }


def check_array(
    where: str,
    value: object,
    dtype: np.dtype,
    shape: Sequence[Optional[int]],
    finite: bool = True,
) -> np.ndarray:
    """Return ``value`` as an ndarray after checking its dtype, shape and (optionally) finiteness.

    ``shape`` may contain ``None`` for an axis of any length. No value conversion is ever done:
    a float64 array passed for a float32 field (or a big-endian one) is refused.
    """
    if not isinstance(value, np.ndarray):
        raise DataError.at(where, f"expected a numpy array of {dtype.name}, got {type(value).__name__}")
    if value.dtype != dtype:
        got = value.dtype.str if value.dtype.name == dtype.name else value.dtype.name
        raise DataError.at(where, f"expected dtype {dtype.name} ({dtype.str}), got {got}")
    if value.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(value.shape, shape)
    ):
        want_txt = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise DataError.at(where, f"expected shape {want_txt}, got {list(value.shape)}")
    if finite and value.dtype.kind == "f" and value.size and not np.isfinite(value).all():
        bad = int(np.size(value) - np.count_nonzero(np.isfinite(value)))
        raise DataError.at(where, f"expected finite values, found {bad} NaN/inf")
    return value


def check_index(where: str, value: object) -> int:
    """Return ``value`` as a Python int in ``[0, MAX_INDEX]`` or raise :class:`DataError`."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise DataError.at(where, f"expected a non-negative integer, got {type(value).__name__}")
    v = int(value)
    if not 0 <= v <= MAX_INDEX:
        raise DataError.at(where, f"expected an integer in [0, 2**63-1], got {v}")
    return v


def check_index_array(where: str, value: object, length: int) -> np.ndarray:
    """Return an integer array of ``length`` as contiguous int64, values in ``[0, MAX_INDEX]``."""
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "iu":
        got = value.dtype.name if isinstance(value, np.ndarray) else type(value).__name__
        raise DataError.at(where, f"expected an integer numpy array, got {got}")
    if value.shape != (length,):
        raise DataError.at(where, f"expected shape [{length}], got {list(value.shape)}")
    if value.size and (value.min() < 0 or (value.dtype.kind == "u" and value.max() > MAX_INDEX)):
        raise DataError.at(where, "expected integers in [0, 2**63-1]")
    return np.ascontiguousarray(value, dtype=INDEX_DTYPE)


# --------------------------------------------------------------------------------------------
# containers


@dataclass(eq=False)
class Episode:
    """One rollout as given to a shard writer: ``T`` recorded steps of ``N`` robots.

    Attributes:
        episode_id: dataset-wide id of the rollout (int, ``>= 0``).
        scenario_seed: seed of the scenario the rollout ran on (int, ``>= 0``).
        actions: ``[T, N, 2]`` float32, expert velocity U0 in m/s.
        positions: ``[T, N, 2]`` float32, robot positions X in m.
        observations: ``[T, N, 4, 32, 32]`` float16, observations O (local, comm_x, comm_y,
            obstacle).
        steps: ``[T]`` int64, simulation step of each record, strictly increasing. Any integer
            dtype is accepted and stored as int64.
        world_map: optional ``[Wx, Wy]`` float32 importance map indexed ``[x, y]`` (x east),
            1 m cells (W = 1024 typically). Only for visualisation (MCAP ``/world/map``); it is not
            part of a sample and readers do not return it.
        goals: optional ``[T, N, 2]`` float32, the expert's Voronoi centroids in m. Only for
            visualisation (MCAP ``/expert/goals``).

    Construction validates dtypes, shapes, finiteness and index ranges and raises
    :class:`DataError` naming the offending field.
    """

    episode_id: int
    scenario_seed: int
    actions: np.ndarray
    positions: np.ndarray
    observations: np.ndarray
    steps: np.ndarray
    world_map: Optional[np.ndarray] = None
    goals: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        self.episode_id = check_index("Episode.episode_id", self.episode_id)
        self.scenario_seed = check_index("Episode.scenario_seed", self.scenario_seed)
        check_array("Episode.actions", self.actions, ACTIONS_DTYPE, (None, None, 2))
        t, n = self.actions.shape[:2]
        if t == 0 or n == 0:
            raise DataError.at("Episode.actions", f"expected at least one step and one robot, got shape {list(self.actions.shape)}")
        check_array("Episode.positions", self.positions, POSITIONS_DTYPE, (t, n, 2))
        check_array("Episode.observations", self.observations, OBSERVATIONS_DTYPE, (t, n, *OBS_SHAPE))
        self.steps = check_index_array("Episode.steps", self.steps, t)
        if t > 1 and not (np.diff(self.steps) > 0).all():
            raise DataError.at("Episode.steps", "expected strictly increasing simulation steps")
        if self.world_map is not None:
            check_array("Episode.world_map", self.world_map, WORLD_MAP_DTYPE, (None, None))
            if self.world_map.size == 0:
                raise DataError.at("Episode.world_map", "expected a non-empty [Wx, Wy] map")
        if self.goals is not None:
            check_array("Episode.goals", self.goals, GOALS_DTYPE, (t, n, 2))

    @property
    def num_steps(self) -> int:
        """Number of recorded steps ``T``."""
        return int(self.actions.shape[0])

    @property
    def num_robots(self) -> int:
        """Number of robots ``N``."""
        return int(self.actions.shape[1])

    def to_batch(self) -> "SampleBatch":
        """The episode's samples as a :class:`SampleBatch` (arrays are shared, not copied)."""
        t = self.num_steps
        return SampleBatch(
            episode_id=np.full(t, self.episode_id, dtype=INDEX_DTYPE),
            step=self.steps,
            scenario_seed=np.full(t, self.scenario_seed, dtype=INDEX_DTYPE),
            actions=self.actions,
            positions=self.positions,
            observations=self.observations,
        )


@dataclass(eq=False)
class SampleBatch:
    """``B`` samples stacked along the first axis, as returned by the shard readers.

    Attributes:
        episode_id: ``[B]`` int64.
        step: ``[B]`` int64 simulation step.
        scenario_seed: ``[B]`` int64.
        actions: ``[B, N, 2]`` float32, m/s.
        positions: ``[B, N, 2]`` float32, m.
        observations: ``[B, N, 4, 32, 32]`` float16.

    Construction checks dtypes and shapes (cheap); :meth:`validate` additionally checks that all
    float values are finite (a full pass over the data).
    """

    episode_id: np.ndarray
    step: np.ndarray
    scenario_seed: np.ndarray
    actions: np.ndarray
    positions: np.ndarray
    observations: np.ndarray

    def __post_init__(self) -> None:
        check_array("SampleBatch.actions", self.actions, ACTIONS_DTYPE, (None, None, 2), finite=False)
        b, n = self.actions.shape[:2]
        check_array("SampleBatch.positions", self.positions, POSITIONS_DTYPE, (b, n, 2), finite=False)
        check_array(
            "SampleBatch.observations", self.observations, OBSERVATIONS_DTYPE, (b, n, *OBS_SHAPE), finite=False
        )
        self.episode_id = check_index_array("SampleBatch.episode_id", self.episode_id, b)
        self.step = check_index_array("SampleBatch.step", self.step, b)
        self.scenario_seed = check_index_array("SampleBatch.scenario_seed", self.scenario_seed, b)

    def __len__(self) -> int:
        return int(self.actions.shape[0])

    @property
    def num_samples(self) -> int:
        """Number of samples ``B``."""
        return len(self)

    @property
    def num_robots(self) -> int:
        """Number of robots ``N``."""
        return int(self.actions.shape[1])

    def validate(self, where: str = "SampleBatch") -> "SampleBatch":
        """Check all float arrays are finite; return ``self``. Raises :class:`DataError`."""
        for name in ("actions", "positions", "observations"):
            arr = getattr(self, name)
            check_array(f"{where}.{name}", arr, arr.dtype, arr.shape, finite=True)
        return self

    def slice(self, start: int, stop: int) -> "SampleBatch":
        """Samples ``start:stop`` (views, no copy)."""
        s = np.s_[start:stop]
        return SampleBatch(
            episode_id=self.episode_id[s],
            step=self.step[s],
            scenario_seed=self.scenario_seed[s],
            actions=self.actions[s],
            positions=self.positions[s],
            observations=self.observations[s],
        )

    @staticmethod
    def concat(batches: Sequence["SampleBatch"]) -> "SampleBatch":
        """Concatenate batches with the same ``N`` along the sample axis (copies)."""
        if not batches:
            raise DataError.at("SampleBatch.concat", "expected at least one batch")
        n = batches[0].num_robots
        for b in batches:
            if b.num_robots != n:
                raise DataError.at("SampleBatch.concat", f"expected {n} robots in every batch, got {b.num_robots}")
        return SampleBatch(
            **{
                name: np.concatenate([getattr(b, name) for b in batches])
                for name in ("episode_id", "step", "scenario_seed", "actions", "positions", "observations")
            }
        )

    @staticmethod
    def empty(num_samples: int, num_robots: int) -> "SampleBatch":
        """A batch of ``num_samples`` uninitialised samples (to be filled in place by a reader)."""
        return SampleBatch(
            episode_id=np.zeros(num_samples, INDEX_DTYPE),
            step=np.zeros(num_samples, INDEX_DTYPE),
            scenario_seed=np.zeros(num_samples, INDEX_DTYPE),
            actions=np.empty((num_samples, num_robots, 2), ACTIONS_DTYPE),
            positions=np.empty((num_samples, num_robots, 2), POSITIONS_DTYPE),
            observations=np.empty((num_samples, num_robots, *OBS_SHAPE), OBSERVATIONS_DTYPE),
        )


# --------------------------------------------------------------------------------------------
# regrouping samples into episodes


def iter_episodes(batches: Iterable[SampleBatch], where: str = "samples") -> Iterator[Episode]:
    """Regroup a stream of batches into :class:`Episode` objects (without visualisation extras).

    Samples of one episode must be contiguous in the stream (as every shard writer lays them out)
    and share one ``scenario_seed``; only the current episode is buffered, so this streams.
    Raises :class:`DataError` (prefixed by ``where``) if an episode id reappears later.
    """
    pending: list[SampleBatch] = []
    seen: set[int] = set()

    def flush() -> Episode:
        b = pending[0] if len(pending) == 1 else SampleBatch.concat(pending)
        pending.clear()
        eid = int(b.episode_id[0])
        if eid in seen:
            raise DataError.at(where, f"episode {eid} is not contiguous (its samples appear in two places)")
        seen.add(eid)
        seeds = np.unique(b.scenario_seed)
        if seeds.size != 1:
            raise DataError.at(where, f"episode {eid} has {seeds.size} different scenario_seed values, expected 1")
        return Episode(
            episode_id=eid,
            scenario_seed=int(seeds[0]),
            actions=b.actions,
            positions=b.positions,
            observations=b.observations,
            steps=b.step,
        )

    for batch in batches:
        if len(batch) == 0:
            continue
        ids = batch.episode_id
        # boundaries where the episode id changes inside this batch
        cuts = np.flatnonzero(ids[1:] != ids[:-1]) + 1
        starts = np.concatenate(([0], cuts))
        stops = np.concatenate((cuts, [len(batch)]))
        for a, z in zip(starts.tolist(), stops.tolist()):
            if pending and int(pending[-1].episode_id[-1]) != int(ids[a]):
                yield flush()
            pending.append(batch.slice(a, z))
    if pending:
        yield flush()


__all__ = [
    "ACTIONS_DTYPE",
    "DEFAULT_NUM_ROBOTS",
    "DataError",
    "Episode",
    "GOALS_DTYPE",
    "INDEX_DTYPE",
    "OBSERVATIONS_DTYPE",
    "OBS_CHANNELS",
    "OBS_SHAPE",
    "OBS_SIZE",
    "POSITIONS_DTYPE",
    "SCHEMA_VERSION",
    "SampleBatch",
    "WORLD_MAP_DTYPE",
    "check_array",
    "check_index",
    "check_index_array",
    "iter_episodes",
    "sample_shapes",
]
