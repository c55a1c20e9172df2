"""In-memory schema: validation of Episode/SampleBatch and regrouping samples into episodes."""

from __future__ import annotations

import numpy as np
import pytest

from madp.data_schema import DataError, Episode, SampleBatch, iter_episodes

from .conftest import assert_bit_equal, batch_of, random_episodes


def _kwargs(t=3, n=4):
    return dict(
        episode_id=1,
        scenario_seed=2,
        actions=np.zeros((t, n, 2), np.float32),
        positions=np.zeros((t, n, 2), np.float32),
        observations=np.zeros((t, n, 4, 32, 32), np.float16),
        steps=np.arange(t) * 5,
    )


def test_valid_episode_properties():
    ep = Episode(**_kwargs())
    assert (ep.num_steps, ep.num_robots) == (3, 4)
    assert ep.steps.dtype == np.int64


@pytest.mark.parametrize(
    "field, value, fragment",
    [
        ("actions", np.zeros((3, 4, 2), np.float64), "Episode.actions: expected dtype float32"),
        ("positions", np.zeros((3, 5, 2), np.float32), "Episode.positions: expected shape [3, 4, 2]"),
        ("observations", np.zeros((3, 4, 4, 32, 32), np.float32), "Episode.observations: expected dtype float16"),
        ("observations", np.zeros((3, 4, 3, 32, 32), np.float16), "Episode.observations: expected shape"),
        ("steps", np.array([0, 5, 5]), "Episode.steps: expected strictly increasing"),
        ("steps", np.array([0.0, 1.0, 2.0]), "Episode.steps: expected an integer"),
        ("episode_id", -1, "Episode.episode_id"),
        ("scenario_seed", 1.5, "Episode.scenario_seed"),
        ("world_map", np.zeros((8, 8), np.float64), "Episode.world_map: expected dtype float32"),
        ("goals", np.zeros((2, 4, 2), np.float32), "Episode.goals: expected shape [3, 4, 2]"),
        ("actions", np.zeros((3, 4, 2), np.float32).astype(">f4"), "Episode.actions: expected dtype float32 (<f4), got >f4"),
    ],
)
def test_episode_validation_names_field(field, value, fragment):
    kw = _kwargs()
    kw[field] = value
    with pytest.raises(DataError) as exc:
        Episode(**kw)
    assert fragment in str(exc.value)
    assert "\n" not in str(exc.value)


def test_non_finite_refused():
    kw = _kwargs()
    kw["observations"][1, 2, 3, 4, 5] = np.inf
    with pytest.raises(DataError, match=r"Episode.observations: expected finite values, found 1 NaN/inf"):
        Episode(**kw)
    kw = _kwargs()
    kw["actions"][0, 0, 0] = np.nan
    with pytest.raises(DataError, match="Episode.actions: expected finite"):
        Episode(**kw)


def test_data_error_is_one_line():
    assert str(DataError("a\nb\n  c")) == "a b c"
    assert str(DataError.at("f.mcap", "bad\nthing")) == "f.mcap: bad thing"


def test_sample_batch_shapes_and_validate():
    b = batch_of(random_episodes())
    assert (b.num_samples, b.num_robots) == (12, 6)
    b.validate()
    bad = SampleBatch.empty(2, 3)
    bad.actions[:] = np.nan
    bad.positions[:] = 0
    bad.observations[:] = 0
    with pytest.raises(DataError, match="SampleBatch.actions: expected finite"):
        bad.validate()
    with pytest.raises(DataError, match="SampleBatch.positions: expected shape"):
        SampleBatch(**{**b.__dict__, "positions": b.positions[:, :3]})


def test_iter_episodes_regroups_across_batch_boundaries():
    eps = random_episodes(lengths=(5, 3, 4), with_extras=False)
    full = batch_of(eps)
    # cut the stream at awkward places: inside episodes and on boundaries
    cuts = [0, 2, 5, 7, 12]
    pieces = [full.slice(a, z) for a, z in zip(cuts[:-1], cuts[1:])]
    back = list(iter_episodes(pieces))
    assert [e.episode_id for e in back] == [e.episode_id for e in eps]
    for a, b in zip(eps, back):
        assert a.scenario_seed == b.scenario_seed
        assert_bit_equal(a.to_batch(), b.to_batch())


def test_iter_episodes_refuses_non_contiguous_episode():
    eps = random_episodes(lengths=(2, 2), with_extras=False)
    b = batch_of([eps[0], eps[1], eps[0]])
    with pytest.raises(DataError, match="episode 100 is not contiguous"):
        list(iter_episodes([b], where="x.mcap"))
