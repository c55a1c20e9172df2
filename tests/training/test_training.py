"""Streaming, exact resume, checkpoints and DDP of ``madp train`` on a tiny dataset."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from madp.data_schema.dataset import open_dataset
from madp.datagen import DatagenConfig, run_datagen
from madp.errors import InputError, SettingError
from madp.models import MADP, madp_config
from madp.sim import SimParams
from madp.training import ShardStream, StreamPosition, load_policy, resolve, train
from madp.training.config import learning_rate
from tests.conftest import one_torch_thread, tiny_dataset
from tests.test_reliability_errors import cli


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return tiny_dataset(tmp_path_factory, "data")  # in this process: no worker to start


def ids(stream):
    return [(int(s["pos_m"][0, 0] * 1e4), int(s["pos_m"][0, 1] * 1e4), int(s["actions"][0, 0] * 1e4)) for s in stream]


def test_streams_split_data_without_repeats(dataset):
    m = open_dataset(dataset)
    total = m.splits["train"].num_samples
    seen = []
    for rank in range(2):
        s = ShardStream(dataset, m, "train", seed=5, batch_size=4, buffer_size=8, rank=rank, world_size=2)
        seen.append(ids(s))
    assert len(seen[0]) == len(seen[1]) > 0 and len(seen[0]) % 4 == 0
    assert not set(seen[0]) & set(seen[1])
    assert len(seen[0]) * 2 > total - 2 * 16  # at most a shard's worth skipped per stream
    again = ids(ShardStream(dataset, m, "train", seed=5, batch_size=4, buffer_size=8, rank=0, world_size=2))
    assert again == seen[0]  # deterministic per (seed, epoch)
    s = ShardStream(dataset, m, "train", seed=5, batch_size=4, buffer_size=8)
    s.set_position(StreamPosition(1, 0))
    epoch1 = ids(s)
    s.set_position(StreamPosition(0, 0))
    assert ids(s) != epoch1  # a new order each epoch
    s.set_position(StreamPosition(1, 12))
    assert ids(s) == epoch1[12:]  # resume mid-epoch


def test_d4_augmented_stream_is_an_image_of_the_plain_one_and_resumes_exactly(dataset):
    """--augment d4: the k-th sample is one of the 8 images of the k-th plain sample (same order,
    same world size as the dataset's 256 m), about 7/8 of them changed, and a resumed epoch draws
    the same transforms (fails if skipped samples did not consume their draws)."""
    from madp.models.symmetry import transform_sample

    m = open_dataset(dataset)
    plain = list(ShardStream(dataset, m, "train", seed=5, batch_size=4, buffer_size=8))
    aug_stream = ShardStream(dataset, m, "train", seed=5, batch_size=4, buffer_size=8, augment="d4")
    aug = list(aug_stream)
    assert aug_stream.world_size_m == 256.0 and len(aug) == len(plain)
    changed = 0
    for p, a in zip(plain, aug):
        images = [transform_sample(p["obs"], p["pos_m"], p["actions"], g, 256.0) for g in range(8)]
        match = [g for g, (o, x, u) in enumerate(images)
                 if torch.allclose(o, a["obs"]) and torch.allclose(x, a["pos_m"]) and torch.allclose(u, a["actions"])]
        assert match, "an augmented sample is no D4 image of the plain one"
        changed += match[0] != 0
    assert 0.6 * len(aug) < changed < len(aug)
    aug_stream.set_position(StreamPosition(0, 12))
    assert all(torch.equal(x["obs"], y["obs"]) for x, y in zip(aug_stream, aug[12:]))
    with pytest.raises(SettingError, match="^augment: expected one of"):
        ShardStream(dataset, m, "train", seed=5, augment="c4")


def losses(run: Path):
    lines = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    return [(d["step"], d["loss"]) for d in lines if "loss" in d], [d["val_loss"] for d in lines if "val_loss" in d]


@pytest.mark.parametrize("model,workers", [("madp", 0), ("lpac", 0), ("madp", 2)])
def test_exact_resume(dataset, tmp_path, model, workers):
    """Stopped after 5 steps and resumed, a run logs the same losses, learning rates and weights as
    an uninterrupted one. With 2 loader workers each worker's stream position must be
    restored too: fails if a resumed worker restarts its shards or skips another worker's."""
    kw = dict(data=str(dataset), epochs=2, batch_size=8, num_workers=workers, log_every=1, val_samples=16,
              checkpoint_every=3, seed=7, warmup_steps=2)  # cpu preset: cosine schedule
    full = resolve(model, "cpu", out=str(tmp_path / "full"), **kw)
    train(full, progress=False)
    part = resolve(model, "cpu", out=str(tmp_path / "part"), stop_after_steps=5, **kw)
    assert train(part, progress=False)["stopped"] == "stop_after_steps"
    train(resolve(model, "cpu", out=str(tmp_path / "part"), **kw), resume=True, progress=False)
    assert losses(tmp_path / "full") == losses(tmp_path / "part")
    lrs = [json.loads(x)["lr"] for x in (tmp_path / "part" / "metrics.jsonl").read_text().splitlines()
           if '"lr"' in x]
    total = len(lrs)
    assert lrs == [learning_rate(full, s, total) for s in range(total)]  # the schedule survives the resume
    a, ma = load_policy(tmp_path / "full" / "checkpoints" / "latest" / "policy.safetensors")
    b, mb = load_policy(tmp_path / "part" / "checkpoints" / "latest" / "policy.safetensors")
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items()):
        assert torch.equal(x, y), k
    assert ma["kind"] == model and ma["action_stats"]["count"] > 0


def test_checkpoint_loads_without_code_and_refuses_garbage(dataset, tmp_path):
    run = tmp_path / "r"
    train(resolve("madp", "cpu", data=str(dataset), out=str(run), epochs=1, batch_size=8, num_workers=0,
                  val_samples=8), progress=False)
    state = torch.load(run / "checkpoints" / "latest" / "state.pt", weights_only=True)
    assert state["step"] > 0
    model, meta = load_policy(run / "checkpoints" / "best" / "policy.safetensors")
    assert torch.allclose(model.action_std, torch.tensor(meta["action_stats"]["std"], dtype=torch.float32))
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes((run / "checkpoints" / "best" / "policy.safetensors").read_bytes()[:1000])
    with pytest.raises(ValueError, match="bad.safetensors"):
        load_policy(bad)
    code, err = cli("train", "--data", dataset, "--out", run)  # in this process, as madp runs it: no start-up
    assert code == 2 and "--resume" in err


_BN_BUFFERS = ("running_mean", "running_var", "num_batches_tracked")


def test_torchrun_two_cpu_processes_stay_in_sync_and_equal_one_process(dataset, tmp_path):
    """Two DDP ranks hold identical weights, see disjoint samples, and train exactly as one process
    with ``--grad-accum 2`` and two loader workers (the same two streams, the same global batch,
    the same noise per sample). Fails if the noise depended on the rank or the gradients were
    summed instead of averaged."""
    run = tmp_path / "ddp"
    env = dict(os.environ, OMP_NUM_THREADS="1")
    common = ["--data", str(dataset), "--epochs", "1", "--batch-size", "4", "--val-samples", "8",
              "--max-steps-per-epoch", "6"]
    torchrun = shutil.which("torchrun", path=str(Path(sys.executable).parent)) or "torchrun"
    r = subprocess.run([torchrun, "--standalone", "--nproc_per_node=2", "-m", "madp.cli", "train", "--out", str(run),
                        "--workers", "0", *common], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    sync = [d for d in lines if "ddp_param_checksums" in d]
    assert sync and len(set(sync[-1]["ddp_param_checksums"])) == 1 and len(sync[-1]["ddp_param_checksums"]) == 2
    assert sync[-1]["ddp_samples_per_rank"][0] == sync[-1]["ddp_samples_per_rank"][1] > 0
    assert sync[-1]["ddp_overlap"] == 0
    def single(name: str, accum: int) -> dict:
        """``madp train`` in this process (one torch thread, as the ranks), its loader workers forked from it."""
        with one_torch_thread():
            code, err = cli("train", "--out", tmp_path / name, "--workers", "2", "--grad-accum", accum, *common)
        assert code == 0, err[-2000:]
        return load_file(str(tmp_path / name / "checkpoints" / "latest" / "model.safetensors"))

    def distance(a: dict, b: dict) -> float:
        """Over the trained parameters. BatchNorm's running statistics are buffers, not trained: DDP
        keeps rank 0's (PyTorch's broadcast_buffers), accumulation updates them at every micro-batch."""
        assert sorted(a) == sorted(b)
        return max(float((a[k] - b[k]).abs().max()) for k in a if not k.endswith(_BN_BUFFERS))

    ddp = load_file(str(run / "checkpoints" / "latest" / "model.safetensors"))
    assert distance(ddp, single("accum", 2)) < 1e-7  # measured: 0.0
    # other batches (one worker's stream at a time) and other noise: the comparison tells runs apart
    assert distance(ddp, single("plain", 1)) > 1e-6  # measured: 2.7e-5 after 6 warm-up steps


def test_a_process_group_made_by_the_caller_trains_through_ddp(dataset, tmp_path):
    """A single-rank gloo group initialised before ``train`` (what the NCCL test of a one-GPU machine
    does, tests/training/test_cuda_training.py): the run goes through DDP (the closing rank check is
    logged) and trains exactly as the plain run."""
    import torch.distributed as dist

    kw = dict(data=str(dataset), epochs=1, batch_size=8, num_workers=0, val_samples=8, max_steps_per_epoch=3,
              lr=1e-3, warmup_steps=0)
    dist.init_process_group("gloo", init_method=f"file://{tmp_path / 'store'}", rank=0, world_size=1)
    try:
        with one_torch_thread():
            train(resolve("madp", "cpu", out=str(tmp_path / "ddp"), **kw), progress=False)
    finally:
        assert not dist.is_initialized()  # train() ends the group it trained in
    with one_torch_thread():
        train(resolve("madp", "cpu", out=str(tmp_path / "plain"), **kw), progress=False)
    sync = [d for d in map(json.loads, (tmp_path / "ddp" / "metrics.jsonl").read_text().splitlines())
            if "ddp_param_checksums" in d]
    assert len(sync) == 1 and len(sync[0]["ddp_param_checksums"]) == 1
    assert "ddp_param_checksums" not in (tmp_path / "plain" / "metrics.jsonl").read_text()
    ddp = load_file(str(tmp_path / "ddp" / "checkpoints" / "latest" / "model.safetensors"))
    plain = load_file(str(tmp_path / "plain" / "checkpoints" / "latest" / "model.safetensors"))
    assert all(torch.equal(ddp[k], plain[k]) for k in plain)
    torch.manual_seed(0)  # the run's seed: the weights it started from (as the cuda test computes them)
    init = MADP(madp_config("cpu")).state_dict()
    moved = torch.cat([(plain[k] - init[k]).flatten() for k, _ in MADP(madp_config("cpu")).named_parameters()])
    assert float(moved.norm()) > 1e-3


def test_stop_after_minutes_checkpoints_and_logs_the_last_step(dataset, tmp_path):
    cfg = resolve("madp", "cpu", data=str(dataset), out=str(tmp_path / "r"), epochs=1, batch_size=8, num_workers=0,
                  val_samples=8, stop_after_minutes=1e-9)  # over at the first step
    assert train(cfg, progress=False) == {"stopped": "stop_after_minutes", "step": 1}
    lines = [json.loads(x) for x in (tmp_path / "r" / "metrics.jsonl").read_text().splitlines()]
    assert [d["step"] for d in lines if "loss" in d] == [1]  # logged although log_every is 10
    assert torch.load(tmp_path / "r" / "checkpoints" / "latest" / "state.pt", weights_only=True)["step"] == 1
    code, err = cli("train", "--data", dataset, "--out", tmp_path / "bad", "--stop-after-minutes", "-1")
    assert code == 2 and "--stop-after-minutes" in err


def test_cosine_schedule_warms_up_then_decays_to_five_percent():
    cfg = resolve("madp", "cpu", warmup_steps=10)
    lrs = [learning_rate(cfg, s, 1000) for s in range(1001)]
    assert lrs[0] == pytest.approx(cfg.lr * 0.1, rel=1e-3) and lrs[9] == pytest.approx(cfg.lr, rel=1e-3)
    assert all(a >= b for a, b in zip(lrs[10:], lrs[11:]))  # monotone decay after warm-up
    assert lrs[500] == pytest.approx(cfg.lr * 0.525) and lrs[1000] == pytest.approx(cfg.lr * 0.05)
    paper = resolve("madp", "paper")
    assert {learning_rate(paper, s, 1000) for s in (0, 500, 999)} == {paper.lr}  # the paper's constant lr


def test_epoch_shards_weight_each_dataset():
    from madp.training.stream import epoch_shards

    groups = [[0, 1, 2, 3], [4, 5]]
    assert epoch_shards(groups, [1, 1], seed=0, epoch=0) == [0, 1, 2, 3, 4, 5]
    two = epoch_shards(groups, [2, 0.5], seed=0, epoch=0)
    assert two[:8] == [0, 1, 2, 3] * 2 and len(two) == 9 and two[8] in (4, 5)
    assert two == epoch_shards(groups, [2, 0.5], seed=0, epoch=0)  # a function of (seed, epoch)
    picks = {epoch_shards(groups, [1, 0.5], seed=0, epoch=e)[-1] for e in range(20)}
    assert picks == {4, 5}  # the half of dataset 2 changes from epoch to epoch


def test_training_on_several_datasets(dataset, tmp_path):
    """Several --data directories (DAgger rounds): the stream mixes their train splits by weight,
    the first one's statistics and val split are used, and config.json names every dataset."""
    other = tmp_path / "round1"
    run_datagen(DatagenConfig(160, seed=9, samples_per_shard=16,
                              params=SimParams(world_size=256, num_robots=4, num_features=4)), other, workers=1,
                progress=False)
    m1, m2 = open_dataset(dataset), open_dataset(other)
    one = sum(1 for _ in ShardStream(dataset, m1, "train", seed=5, buffer_size=8))
    mixed = list(ShardStream([dataset, other], [m1, m2], "train", seed=5, buffer_size=8, weights=[1, 2]))
    assert len(mixed) == one + 2 * m2.splits["train"].num_samples
    cfg = resolve("lpac", "cpu", data=str(dataset), more_data=(str(other),), data_weights=(1, 2),
                  out=str(tmp_path / "run"), epochs=1, batch_size=4, max_steps_per_epoch=3, val_samples=8)
    train(cfg, progress=False)
    meta = json.loads((tmp_path / "run" / "config.json").read_text())
    assert meta["dataset"]["root"] == str(dataset) and meta["dataset"]["more"][0]["root"] == str(other)
    assert meta["dataset"]["more"][0]["weight"] == 2 and meta["action_stats"] == m1.action_stats.to_dict()
    with pytest.raises(SettingError, match="^data_weights: expected 2 positive numbers"):
        resolve("lpac", "cpu", data=str(dataset), more_data=(str(other),), data_weights=(1,))


def test_init_warm_starts_from_a_policy_file_and_refuses_another_model(dataset, tmp_path):
    from madp.training.trainer import Trainer

    first = resolve("lpac", "cpu", data=str(dataset), out=str(tmp_path / "a"), epochs=1, batch_size=4,
                    max_steps_per_epoch=2, val_samples=8)
    train(first, progress=False)
    src = tmp_path / "a" / "checkpoints" / "best" / "policy.safetensors"
    warm = Trainer(resolve("lpac", "cpu", data=str(dataset), out=str(tmp_path / "b"), init=str(src)), progress=False)
    ref, _ = load_policy(src)
    for k, v in ref.state_dict().items():
        assert torch.equal(warm.raw.state_dict()[k], v), k
    assert warm.step == 0 and json.loads((tmp_path / "b" / "config.json").read_text())["init"]["path"] == str(src)
    with pytest.raises(InputError, match="init needs a madp checkpoint"):
        Trainer(resolve("madp", "cpu", data=str(dataset), out=str(tmp_path / "c"), init=str(src)), progress=False)


def test_shipped_checkpoints_match_their_record_load_and_act_like_trained_policies():
    """madp/checkpoints/ (what ``madp eval`` uses by default): each file has the size and sha256 its
    provenance records, loads as its kind with the dataset's action statistics, and steers like a
    trained policy: on 4 fresh 32-robot worlds its first actions point the way the clairvoyant
    expert's (the dataset's teacher) do: mean cosine > 0.3 (measured 0.49 for MADP, 0.53 for
    LPAC-K3; -0.1 .. 0.1 for untrained networks). Fails on a corrupted or stale file, a broken
    loader, or lost action statistics."""
    import hashlib

    from madp.policies import SHIPPED, MADPPolicy, load, shipped_checkpoint
    from madp.policies.lpac import LPACPolicy
    from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario, SimParams

    prov = json.loads((Path(__file__).resolve().parents[2] / "madp" / "checkpoints" / "provenance.json").read_text())
    envs = [CoverageEnv(Scenario.random(seed, SimParams())) for seed in range(4)]
    expert = [ClairvoyantCVT()(env) for env in envs]
    for kind, name in SHIPPED.items():
        path = shipped_checkpoint(kind)
        assert path is not None and path.name in prov["checkpoints"], kind
        rec = prov["checkpoints"][path.name]
        data = path.read_bytes()
        assert len(data) == rec["bytes"] and hashlib.sha256(data).hexdigest() == rec["sha256"], name
        model, meta = load(path, kind)
        stats = rec["dataset"]["action_stats"]
        assert torch.allclose(model.action_mean, torch.tensor(stats["mean"], dtype=torch.float32))
        assert torch.allclose(model.action_std, torch.tensor(stats["std"], dtype=torch.float32))
        policy = MADPPolicy(model, seed=0) if kind == "madp" else LPACPolicy(model)
        cos = []
        for env, u_star in zip(envs, expert):
            u = policy(env)
            assert u.shape == (32, 2) and np.isfinite(u).all()
            assert np.linalg.norm(u, axis=1).max() <= env.params.max_speed_mps + 1e-9
            cos.append(np.mean((u * u_star).sum(1) / (np.linalg.norm(u, axis=1) * np.linalg.norm(u_star, axis=1) + 1e-12)))
        assert np.mean(cos) > 0.3, (kind, cos)
