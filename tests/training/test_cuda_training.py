"""Training on a CUDA GPU (marked ``cuda``: skipped without one; ``scripts/gpu_paper.sh`` runs them):
steps under bf16 autocast, checkpoints saved on one device and loaded on the other, and the DDP path
with NCCL in a single-GPU world. Each test asserts that it really ran on the GPU."""

import json
import os
import subprocess
import sys

import pytest
import torch
import torch.distributed as dist
from safetensors.torch import load_file

from madp.models import MADP, madp_config
from madp.policies.parts import write_fp16
from madp.training import load_policy, resolve, train
from madp.training.checkpoint import save_policy
from madp.training.trainer import Trainer
from tests.conftest import tiny_dataset

pytestmark = pytest.mark.cuda
META = {"action_stats": {"count": 1, "mean": [0.0, 0.0], "std": [2.0, 2.0]}}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return tiny_dataset(tmp_path_factory, "cuda-data")


def config(dataset, out, model="madp", **kw):
    kw = {"epochs": 1, "batch_size": 8, "num_workers": 0, "val_samples": 8, "log_every": 1, **kw}
    return resolve(model, "cpu", data=str(dataset), out=str(out), **kw)


def losses(run) -> list[float]:
    return [d["loss"] for d in map(json.loads, (run / "metrics.jsonl").read_text().splitlines()) if "loss" in d]


def cpu_state(model: torch.nn.Module) -> dict:
    return {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}


@pytest.mark.parametrize("model", ["madp", "lpac"])
def test_training_steps_run_under_bf16_autocast_on_the_gpu(dataset, tmp_path, model):
    """The trainer puts the model on the GPU, its layers compute in bfloat16 (autocast) while the
    weights stay float32, the losses are finite and the weights move."""
    trainer = Trainer(config(dataset, tmp_path / "run", model, stop_after_steps=3), progress=False)
    assert trainer.device.type == "cuda" and next(trainer.raw.parameters()).is_cuda
    head = trainer.raw.head if model == "madp" else trainer.raw.out
    seen: set = set()
    # the training forwards (LPAC-K3's health check and validation run without gradients)
    head.register_forward_hook(lambda mod, args, out: seen.add(out.dtype) if torch.is_grad_enabled() else None)
    before = cpu_state(trainer.raw)
    assert trainer.fit()["stopped"] == "stop_after_steps"
    assert seen == {torch.bfloat16}  # every training forward of the run went through autocast
    assert all(p.dtype == torch.float32 for p in trainer.raw.parameters())
    got = losses(tmp_path / "run")
    assert len(got) == 3 and all(torch.isfinite(torch.tensor(got)))
    after = cpu_state(trainer.raw)
    moved = [k for k in before if before[k].is_floating_point() and not torch.equal(before[k], after[k])]
    assert len(moved) > len(before) // 2, moved
    assert all(torch.isfinite(v).all() for v in after.values() if v.is_floating_point())


def test_checkpoints_cross_devices(dataset, tmp_path):
    """A policy saved by a GPU run loads on the CPU and on the GPU with equal weights; one saved on
    the CPU loads on the GPU; the float16 parts load on the GPU; and the GPU run's training state
    resumes on a machine without a GPU (here: CUDA_VISIBLE_DEVICES empty)."""
    run = tmp_path / "gpu"
    train(config(dataset, run, stop_after_steps=2), progress=False)
    assert json.loads((run / "config.json").read_text())["device"].startswith("cuda")
    policy = run / "checkpoints" / "latest" / "policy.safetensors"
    on_cpu, _ = load_policy(policy, "cpu")
    on_gpu, _ = load_policy(policy, "cuda")
    assert next(on_gpu.parameters()).is_cuda and not next(on_cpu.parameters()).is_cuda
    a, b = cpu_state(on_cpu), cpu_state(on_gpu)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)

    torch.manual_seed(0)
    cpu_model = MADP(madp_config("cpu"))
    save_policy(tmp_path / "cpu.safetensors", cpu_model, "madp", META)
    back, _ = load_policy(tmp_path / "cpu.safetensors", "cuda")
    want, got = cpu_state(cpu_model), cpu_state(back)
    assert all(torch.equal(want[k], got[k]) for k in want)

    files = write_fp16(on_gpu, {"kind": "madp", "config": json.dumps(on_gpu.config.to_dict())},
                       tmp_path / "fp16.safetensors", max_part_bytes=64 << 10)
    assert len(files) > 2  # an index and several parts
    half, _ = load_policy(files[0], "cuda")
    got = cpu_state(half)
    assert next(half.parameters()).dtype == torch.float32
    assert all(torch.allclose(a[k].float(), got[k].float(), atol=1e-3 * (1 + a[k].abs().max().item()), rtol=0)
               for k in a if a[k].is_floating_point())

    env = dict(os.environ, CUDA_VISIBLE_DEVICES="", OMP_NUM_THREADS="1")
    r = subprocess.run([sys.executable, "-m", "madp.cli", "train", "--data", str(dataset), "--out", str(run),
                        "--resume", "--epochs", "1", "--batch-size", "8", "--workers", "0", "--val-samples", "8",
                        "--stop-after-steps", "4"], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads((run / "config.json").read_text())["device"] == "cpu"
    assert torch.load(run / "checkpoints" / "latest" / "state.pt", weights_only=True)["step"] == 4


def test_ddp_with_nccl_in_a_single_gpu_world(dataset, tmp_path):
    """The trainer's DDP path (NCCL all-reduce of the gradients, the closing all_gather of the
    ranks' checksums) in a world of one GPU trains as the plain run does, up to the GPU's
    non-deterministic kernels: the two runs' weight updates agree to a few percent."""
    kw = {"max_steps_per_epoch": 3, "lr": 1e-3, "warmup_steps": 0}
    dist.init_process_group("nccl", init_method=f"file://{tmp_path / 'store'}", rank=0, world_size=1)
    try:
        train(config(dataset, tmp_path / "ddp", **kw), progress=False)
    finally:
        if dist.is_initialized():  # train() destroys the group it trained in
            dist.destroy_process_group()
    train(config(dataset, tmp_path / "plain", **kw), progress=False)
    lines = [json.loads(x) for x in (tmp_path / "ddp" / "metrics.jsonl").read_text().splitlines()]
    sync = [d for d in lines if "ddp_param_checksums" in d]
    assert len(sync) == 1 and len(sync[0]["ddp_param_checksums"]) == 1 and sync[0]["ddp_samples_per_rank"][0] > 0
    assert json.loads((tmp_path / "ddp" / "config.json").read_text())["device"].startswith("cuda")
    torch.manual_seed(0)  # the runs' seed: the trainer builds the model on the CPU, then moves it
    init = MADP(madp_config("cpu")).state_dict()
    ddp = load_file(str(tmp_path / "ddp" / "checkpoints" / "latest" / "model.safetensors"))
    plain = load_file(str(tmp_path / "plain" / "checkpoints" / "latest" / "model.safetensors"))
    trained = [k for k, _ in MADP(madp_config("cpu")).named_parameters()]
    d_ddp = torch.cat([(ddp[k] - init[k]).flatten() for k in trained])
    d_plain = torch.cat([(plain[k] - init[k]).flatten() for k in trained])
    assert float(d_plain.norm()) > 1e-3  # three steps of lr 1e-3 moved the weights
    assert float((d_ddp - d_plain).norm() / d_plain.norm()) < 0.1


def test_comm_dropout_on_the_gpu(dataset, tmp_path):
    """--comm-dropout draws its links on the GPU (a CUDA generator), the neighbour channels computed
    there equal the simulator's bit for bit, and a run with dropout trains to finite losses."""
    import numpy as np

    from madp.sim.observations import neighbour_maps
    from madp.training.comm_dropout import draw_links, neighbour_channels
    from madp.training.loss import step_generator

    rng = np.random.default_rng(0)
    for spread in (10.0, 60.0, 300.0):
        pos = rng.uniform(0.0, spread, (40, 2)) + 50.0
        got = neighbour_channels(torch.from_numpy(pos)[None].cuda(), 256.0)
        assert got.is_cuda
        np.testing.assert_array_equal(got[0].cpu().numpy(), neighbour_maps(pos, 256.0))
    links = draw_links(step_generator(0, 0, torch.device("cuda")), 16, 4, 1.0)
    assert links.is_cuda and not links.all() and torch.equal(links, links.transpose(1, 2))
    train(config(dataset, tmp_path / "run", stop_after_steps=3, comm_dropout=0.5), progress=False)
    got = losses(tmp_path / "run")
    assert len(got) == 3 and all(torch.isfinite(torch.tensor(got)))
    assert json.loads((tmp_path / "run" / "config.json").read_text())["device"].startswith("cuda")
