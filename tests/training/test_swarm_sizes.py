"""Training on datasets of several swarm sizes (e.g. N = 32 and 128): batches of one N, padding with a
valid mask only where a stream's last batches mix sizes, exact resume."""

import math

import pytest
import torch

from madp.data_schema.dataset import open_dataset
from madp.datagen import DatagenConfig, run_datagen
from madp.sim import SimParams
from madp.training import ShardStream, load_policy, resolve, train
from tests.conftest import tiny_dataset
from tests.training.test_training import ids, losses


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return tiny_dataset(tmp_path_factory, "data")


@pytest.fixture(scope="module")
def six_robots(tmp_path_factory):
    """Swarms of 6 robots on the same 256 m world as ``dataset`` (4 robots): training on both."""
    root = tmp_path_factory.mktemp("six")
    run_datagen(DatagenConfig(96, seed=4, samples_per_shard=16,
                              params=SimParams(world_size=256, num_robots=6, num_features=4)), root, workers=1,
                progress=False)
    return root


def test_swarms_of_several_sizes_batch_by_size(dataset, six_robots):
    """Datasets of 4 and 6 robots stream every sample once, in runs of ``batch_size`` of one size
    (only the last batch of a stream may mix, padded with ``valid``); one size alone keeps its order.
    Fails if the stream mixes sizes mid-epoch (default collate cannot stack them) or loses a sample."""
    from madp.training.stream import collate_swarms

    m1, m2 = open_dataset(dataset), open_dataset(six_robots)
    plain = ids(ShardStream(dataset, m1, "train", seed=5, buffer_size=8))
    assert ids(ShardStream(dataset, m1, "train", seed=5, buffer_size=8, batch_size=4)) == plain
    both = ShardStream([dataset, six_robots], [m1, m2], "train", seed=5, buffer_size=8, batch_size=4)
    samples = list(both)
    total = m1.splits["train"].num_samples + m2.splits["train"].num_samples
    assert len(samples) == total - total % 4 and len(set(ids(samples))) == len(samples)
    sizes = [len(s["pos_m"]) for s in samples]
    blocks = [set(sizes[i:i + 4]) for i in range(0, len(sizes), 4)]
    assert all(len(b) == 1 for b in blocks[:-1]) and {4, 6} <= set(sizes)
    mixed = collate_swarms([samples[sizes.index(4)], samples[sizes.index(6)]])
    assert mixed["obs"].shape[:2] == (2, 6) and mixed["valid"].sum(1).tolist() == [4, 6]
    assert float(mixed["obs"][0, 4:].abs().sum()) == 0 and torch.equal(mixed["pos_m"][1], samples[sizes.index(6)]["pos_m"])
    assert "valid" not in collate_swarms(samples[:4])


@pytest.mark.parametrize("model", ["madp", "lpac"])
def test_padded_robots_change_no_loss(dataset, six_robots, model):
    """A batch mixing 4- and 6-robot swarms (padded, ``valid``) has the robot-weighted mean of the two
    swarms' losses alone: padding reaches neither attention, the graph, nor the mean. Fails if
    ``batch_loss`` drops ``valid`` or slices the noise wrongly."""
    from madp.training.stream import collate_swarms
    from madp.training.loss import batch_loss
    from madp.training.trainer import build_model

    m1, m2 = open_dataset(dataset), open_dataset(six_robots)
    a = next(iter(ShardStream(dataset, m1, "train", seed=1)))
    b = next(iter(ShardStream(six_robots, m2, "train", seed=1)))
    cfg = resolve(model, "cpu", data=str(dataset))
    torch.manual_seed(0)
    raw = build_model(cfg, 6).eval()
    noise = torch.randn(2, 6, 2)
    k = torch.tensor([5, 40])
    cpu = torch.device("cpu")
    draws = lambda i, n: (k[i:i + 1], noise[i:i + 1, :n]) if model == "madp" else None  # noqa: E731
    with torch.no_grad():
        both = batch_loss(raw, raw, collate_swarms([a, b]), cfg, (k, noise) if model == "madp" else None, cpu)
        la = batch_loss(raw, raw, collate_swarms([a]), cfg, draws(0, 4), cpu)
        lb = batch_loss(raw, raw, collate_swarms([b]), cfg, draws(1, 6), cpu)
    assert float(both) == pytest.approx((4 * float(la) + 6 * float(lb)) / 10, rel=1e-5)


@pytest.mark.parametrize("model", ["madp", "lpac"])
def test_training_on_several_swarm_sizes_resumes_exactly(dataset, six_robots, tmp_path, model):
    """Training on 4- and 6-robot swarms together (as on 32- and 128-robot datasets), stopped and
    resumed, gives the weights of an unbroken run; the noise is drawn for the largest N."""
    kw = dict(data=str(dataset), more_data=(str(six_robots),), data_weights=(1, 1), epochs=1, batch_size=4,
              max_steps_per_epoch=8, val_samples=8, checkpoint_every=2, seed=3, log_every=1)
    train(resolve(model, "cpu", out=str(tmp_path / "full"), **kw), progress=False)
    assert train(resolve(model, "cpu", out=str(tmp_path / "part"), stop_after_steps=4, **kw),
                 progress=False)["stopped"] == "stop_after_steps"
    train(resolve(model, "cpu", out=str(tmp_path / "part"), **kw), resume=True, progress=False)
    assert losses(tmp_path / "full") == losses(tmp_path / "part")
    assert all(math.isfinite(x) for _, x in losses(tmp_path / "full")[0])
    a, _ = load_policy(tmp_path / "full" / "checkpoints" / "latest" / "policy.safetensors")
    b, _ = load_policy(tmp_path / "part" / "checkpoints" / "latest" / "policy.safetensors")
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items()):
        assert torch.equal(x, y), k
