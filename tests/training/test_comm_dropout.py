"""``madp train --comm-dropout P``: training samples in which robots stop hearing some neighbours."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from madp.data_schema.dataset import open_dataset
from madp.errors import SettingError
from madp.sim.observations import neighbour_maps, view_neighbour_maps
from madp.training import ShardStream, load_policy, resolve, train
from madp.training.comm_dropout import LOSS_RATES, draw_links, drop_neighbour_channels, in_comm_range, neighbour_channels
from madp.training.loss import batch_loss, step_links, step_noise, step_generator
from madp.training.stream import collate_swarms
from madp.training.trainer import build_model
from tests.conftest import one_torch_thread, tiny_dataset
from tests.test_reliability_errors import assert_one_line, cli
from tests.training.test_training import losses

R_C = 256.0
CPU = torch.device("cpu")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return tiny_dataset(tmp_path_factory, "data")


@pytest.fixture(scope="module")
def batch(dataset):
    """8 training samples of 4 robots."""
    stream = ShardStream(dataset, open_dataset(dataset), "train", seed=1)
    return collate_swarms([s for _, s in zip(range(8), stream)])


def random_swarms(seed: int = 0):
    """Swarms of 2-40 robots, packed tightly (several robots in one pixel of a neighbour map) to spread
    past r_c (robots out of range), positions float64 as the simulator's."""
    rng = np.random.default_rng(seed)
    for t in range(12):
        n = int(rng.integers(2, 41))
        yield rng.uniform(0.0, [10.0, 60.0, 300.0, 700.0][t % 4], (n, 2)) + 50.0


# --- the neighbour channels -----------------------------------------------------------------------------
def test_neighbour_channels_equal_the_simulators_bit_for_bit():
    """With every link heard, the simulator's channels (madp.sim.observations.neighbour_maps); with
    links lost, its channels of what each robot knows (view_neighbour_maps). Fails if the pixel, the
    value or the order of the sums in a shared pixel differ (the tight swarms put 3+ robots in one)."""
    crowded = 0
    for s, pos in enumerate(random_swarms()):
        n = len(pos)
        got = neighbour_channels(torch.from_numpy(pos)[None], R_C)[0].numpy()
        np.testing.assert_array_equal(got, neighbour_maps(pos, R_C))
        heard = draw_links(torch.Generator().manual_seed(s), 1, n, 1.0, rates=(0.5,))
        known = (in_comm_range(torch.from_numpy(pos)[None], R_C) & heard)[0].numpy()
        want = view_neighbour_maps(pos, known, np.broadcast_to(pos[None], (n, n, 2)), R_C)
        np.testing.assert_array_equal(neighbour_channels(torch.from_numpy(pos)[None], R_C, heard=heard)[0].numpy(), want)
        pix = np.round((pos[None] - pos[:, None]).astype(np.float32) * np.float32(32 / (2 * R_C)) + np.float32(15.5))
        crowded += max(np.unique(np.c_[np.repeat(np.arange(n), n), pix.reshape(-1, 2)], axis=0, return_counts=True)[1])
    assert crowded > 12 * 3  # the swarms do stack neighbours in a pixel


def test_padding_robots_never_show():
    pos = next(random_swarms(3))
    n = len(pos)
    padded = torch.zeros(1, n + 3, 2, dtype=torch.float64)
    padded[0, :n] = torch.from_numpy(pos)
    padded[0, n:] = padded[0, :3] + 1.0  # padding within range of real robots
    valid = torch.arange(n + 3)[None] < n
    got = neighbour_channels(padded, R_C, valid=valid)[0].numpy()
    np.testing.assert_array_equal(got[:n], neighbour_maps(pos, R_C))
    assert not got[n:].any()


# --- the links ------------------------------------------------------------------------------------------
def test_links_are_symmetric_heard_by_oneself_and_drawn_as_documented():
    links = draw_links(torch.Generator().manual_seed(0), 4000, 6, 0.5)
    assert links.dtype == torch.bool and links.shape == (4000, 6, 6)
    assert torch.equal(links, links.transpose(1, 2)) and links.diagonal(dim1=1, dim2=2).all()
    off = ~torch.eye(6, dtype=torch.bool)
    lost = (~links[:, off]).float().mean(-1)  # each sample's fraction of pairs lost
    hit = lost > 0
    assert 0.45 < float(hit.float().mean()) < 0.55  # P = 0.5 (a dropped sample at q = 0.3 keeps all 15 pairs with p 0.005)
    assert float((lost == 1).float().mean()) == pytest.approx(0.5 / 3, abs=0.03)  # q = 1: every robot alone
    assert float(lost[hit].mean()) == pytest.approx(sum(LOSS_RATES) / 3, abs=0.03)
    assert 1.0 in LOSS_RATES
    assert torch.equal(links, draw_links(torch.Generator().manual_seed(0), 4000, 6, 0.5))
    assert draw_links(torch.Generator().manual_seed(0), 50, 6, 0.0).all()


def test_an_isolated_robot_attends_to_itself_and_hears_nobody(batch):
    """P = 1, q = 1 (the no_comm fault): every robot's mask row is itself, its token's neighbourhood
    offset 0 and its neighbour channels empty; its local map and boundary channels untouched."""
    cfg = resolve("madp", "cpu")
    torch.manual_seed(0)
    model = build_model(cfg, 4).eval()
    obs, pos = batch["obs"], batch["pos_m"]
    assert obs[:, :, 1:3].abs().amax((2, 3, 4)).gt(0).all()  # every robot hears someone in the data
    links = draw_links(torch.Generator().manual_seed(1), 8, 4, 1.0, rates=(1.0,))
    mask = model.attention_mask(pos, None, links)
    assert torch.equal(mask, torch.eye(4, dtype=torch.bool).expand(8, 4, 4))
    alone = drop_neighbour_channels(obs, pos, links, R_C)
    assert not alone[:, :, 1:3].any()
    assert torch.equal(alone[:, :, 0], obs[:, :, 0]) and torch.equal(alone[:, :, 3], obs[:, :, 3])
    assert alone.stride() == obs.stride()  # the loader's channels-last layout kept
    with torch.no_grad():
        tokens = model.embed_tokens(alone, pos, mask)
    assert not tokens[..., -2:].any()


def test_every_link_heard_changes_nothing(batch):
    """links all True: the observations untouched and the loss bit-identical to no links; a robot that
    lost a neighbour gets the channels of the others in the data's float16 precision, the others keep
    theirs."""
    cfg = resolve("madp", "cpu")
    torch.manual_seed(0)
    model = build_model(cfg, 4).eval()
    obs, pos = batch["obs"], batch["pos_m"]
    all_heard = torch.ones(8, 4, 4, dtype=torch.bool)
    assert torch.equal(drop_neighbour_channels(obs, pos, all_heard, R_C), obs)
    draws = step_noise(model, step_generator(0, 0, CPU), batch, 1)
    draws = (draws[0][0], draws[1][0])
    with torch.no_grad():
        plain = batch_loss(model, model, batch, cfg, draws, CPU)
        assert torch.equal(batch_loss(model, model, batch, cfg, draws, CPU, links=all_heard), plain)
        some = draw_links(torch.Generator().manual_seed(2), 8, 4, 1.0, rates=(0.3,))
        assert not torch.equal(batch_loss(model, model, batch, cfg, draws, CPU, links=some), plain)
    out = drop_neighbour_channels(obs, pos, some, R_C)
    lost = (~some).any(-1)
    assert lost.any() and (~lost).any()
    assert torch.equal(out[~lost], obs[~lost])
    want = neighbour_channels(pos, R_C, heard=some).half().float()
    assert torch.equal(out[:, :, 1:3][lost], want[lost])


def test_p_zero_draws_nothing_and_the_diffusion_draws_never_depend_on_p(batch):
    cfg0, cfg = resolve("madp", "cpu"), resolve("madp", "cpu", comm_dropout=0.5)
    assert cfg0.comm_dropout == 0.0 and step_links(cfg0, 3, CPU, batch, 2) is None
    links = step_links(cfg, 3, CPU, batch, 2, num_robots=6)
    assert links.shape == (2, 8, 6, 6) and not links.all()
    assert torch.equal(links, step_links(cfg, 3, CPU, batch, 2, num_robots=6))  # a function of (seed, step)
    model = build_model(cfg, 4)
    a = step_noise(model, step_generator(cfg.seed, 3, CPU), batch, 2)
    b = step_noise(model, step_generator(cfg.seed, 3, CPU), batch, 2)
    assert all(torch.equal(x, y) for x, y in zip(a, b))


def test_padded_robots_change_no_loss_under_dropout(batch):
    """A batch mixing a 4- and a 3-robot swarm (padded) with links lost: the robot-weighted mean of
    the two swarms' losses alone with the same links. Fails if a padding robot counted as a lost
    neighbour or showed in a channel."""
    cfg = resolve("madp", "cpu", comm_dropout=1.0)
    torch.manual_seed(0)
    model = build_model(cfg, 4).eval()
    a = {k: v[0] for k, v in batch.items()}
    b = {k: v[1][:3] if torch.is_tensor(v) and v.dim() > 1 else v[1] for k, v in batch.items()}
    links = draw_links(torch.Generator().manual_seed(5), 2, 4, 1.0, rates=(0.6,))
    noise, k = torch.randn(2, 4, 2, generator=torch.Generator().manual_seed(6)), torch.tensor([7, 60])
    with torch.no_grad():
        both = batch_loss(model, model, collate_swarms([a, b]), cfg, (k, noise), CPU, links=links)
        la = batch_loss(model, model, collate_swarms([a]), cfg, (k[:1], noise[:1]), CPU, links=links[:1])
        lb = batch_loss(model, model, collate_swarms([b]), cfg, (k[1:], noise[1:, :3]), CPU, links=links[1:])
    assert float(both) == pytest.approx((4 * float(la) + 3 * float(lb)) / 7, rel=1e-5)


# --- the option -------------------------------------------------------------------------------------------
TRAIN = ["--epochs", "2", "--batch-size", "8", "--workers", "0", "--val-samples", "16", "--checkpoint-every", "3",
         "--seed", "7", "--max-steps-per-epoch", "4"]


def test_a_run_with_comm_dropout_trains_and_resumes_exactly(dataset, tmp_path):
    """``madp train --comm-dropout 0.5`` end to end; stopped after 5 steps and resumed, the same run logs
    the same losses (training and validation) and ends with the same weights; its losses differ from a
    run without dropout (same data order and diffusion draws)."""
    kw = dict(data=str(dataset), epochs=2, batch_size=8, num_workers=0, val_samples=16, checkpoint_every=3, seed=7,
              max_steps_per_epoch=4, log_every=1)
    with one_torch_thread():
        code, err = cli("train", "--data", dataset, "--out", tmp_path / "full", *TRAIN, "--comm-dropout", "0.5")
        assert code == 0, err[-2000:]
        part = resolve("madp", "cpu", out=str(tmp_path / "part"), comm_dropout=0.5, **kw)
        assert train(replace(part, stop_after_steps=5), progress=False)["stopped"] == "stop_after_steps"
        train(part, resume=True, progress=False)
        train(resolve("madp", "cpu", out=str(tmp_path / "plain"), stop_after_steps=2, **kw), progress=False)
    (full, full_val), (steps, val) = losses(tmp_path / "full"), losses(tmp_path / "part")
    assert len(steps) == 8 and set(full) <= set(steps) and full_val == val and len(val) == 2  # CLI: every 10th step
    plain = losses(tmp_path / "plain")[0]
    assert len(plain) == 2 and all(x != y for (_, x), (_, y) in zip(plain, steps))
    a, meta = load_policy(tmp_path / "full" / "checkpoints" / "latest" / "policy.safetensors")
    b, _ = load_policy(tmp_path / "part" / "checkpoints" / "latest" / "policy.safetensors")
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items()):
        assert torch.equal(x, y), k
    assert meta["train_config"]["comm_dropout"] == 0.5
    assert json.loads((tmp_path / "plain" / "config.json").read_text())["train"]["comm_dropout"] == 0.0


@pytest.mark.parametrize("value", ["-0.1", "1.5", "x", "nan"])
def test_bad_values_are_one_line_naming_the_flag(dataset, tmp_path, value):
    out = tmp_path / "r"
    assert_one_line(*cli("train", "--data", dataset, "--out", out, *TRAIN, "--comm-dropout", value), "--comm-dropout")
    assert not out.exists()


def test_only_madps_ddpm_training_drops_links(dataset, tmp_path):
    assert_one_line(*cli("train", "--model", "lpac", "--data", dataset, "--out", tmp_path / "r", *TRAIN,
                         "--comm-dropout", "0.5"), "--comm-dropout", "LPAC-K3")
    with pytest.raises(SettingError, match="^comm_dropout: only MADP"):
        resolve("madp", "cpu", distill="teacher.safetensors", comm_dropout=0.2)
    with pytest.raises(SettingError, match="^comm_dropout: expected a probability"):
        resolve("madp", "cpu", comm_dropout=True)
