"""``madp bench train`` reports numbers that mean what they say: real training steps of the trainer's own
loss and optimizer, phases that add up, FLOPs proportional to the batch (speeds themselves are machine
dependent and never asserted)."""

import json

import pytest
import torch

from madp.models import MADP, lpac_config, madp_config
from madp.models.lpac import LPAC
from madp.training.bench import PHASES, TrainBenchCase, bench_train, format_train_bench
from madp.training.config import resolve
from madp.training.optim import make_optimizer
from tests.conftest import tiny_dataset
from tests.test_reliability_errors import cli


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return tiny_dataset(tmp_path_factory, "bench-data")


def test_report_is_consistent_and_flops_scale_with_the_batch(dataset):
    """samples/s is the batch over the median of forward + backward + optimizer, every phase is timed
    at every step, the parameter counts are the models', and the counted FLOPs of a step are exactly
    proportional to the batch. Fails if a field is derived wrongly, a phase is dropped, or the counter
    sees only part of the batch."""
    cases = [TrainBenchCase("madp", "cpu", 1, batch_size=2), TrainBenchCase("madp", "cpu", 1, batch_size=4),
             TrainBenchCase("lpac", "cpu", 1, batch_size=2, optimizer_impl="fused")]
    r2, r4, rl = bench_train(cases, dataset, steps=3, warmup=1, measure_matmul=False)
    assert r2["params"] == sum(p.numel() for p in MADP(madp_config("cpu")).parameters())
    assert rl["params"] == sum(p.numel() for p in LPAC(lpac_config("cpu")).parameters())
    for r in (r2, r4, rl):
        assert set(r["phase_s"]) == set(PHASES) and all(v > 0 for v in r["phase_s"].values())
        assert r["steps"] == 3 and r["threads"] == 1 and r["num_robots"] == 4
        assert r["samples_per_s"] == pytest.approx(r["batch_size"] / r["step_s"])
        assert r["achieved_flops_per_s"] == pytest.approx(r["flops_per_step"] / r["step_s"])
    assert r4["flops_per_step"] == 2 * r2["flops_per_step"] > 0
    assert rl["flops_per_step"] > 0 and rl["optimizer_impl"] == "fused"
    table = "\n".join(format_train_bench([r2, rl]))
    assert "madp" in table and "lpac" in table and "fused" in table


def test_matmul_peak_is_measured_in_the_same_run(dataset):
    """With the matmul measurement, the share and the machine-normalised rate follow from it."""
    (r,) = bench_train([TrainBenchCase("madp", "cpu", 1, batch_size=2)], dataset, steps=1, warmup=0)
    assert r["matmul_flops_per_s"] > 0
    assert r["fraction_of_matmul"] == pytest.approx(r["achieved_flops_per_s"] / r["matmul_flops_per_s"])
    assert r["samples_per_matmul_gflop"] == pytest.approx(r["samples_per_s"] / (r["matmul_flops_per_s"] / 1e9))


@pytest.mark.parametrize("impl", ["loop", "foreach", "fused"])
def test_optimizer_implementations_take_the_same_step(impl):
    """The three AdamW implementations ``make_optimizer`` offers compute the same update (to float
    rounding): a bench ablation compares speed, not different optimizers."""
    cfg = resolve("madp", "cpu")
    torch.manual_seed(0)
    ref, other = torch.nn.Linear(8, 4), torch.nn.Linear(8, 4)
    other.load_state_dict(ref.state_dict())
    opts = [make_optimizer(cfg, ref.parameters(), impl="loop"), make_optimizer(cfg, other.parameters(), impl=impl)]
    x = torch.randn(16, 8)
    for _ in range(3):
        for m, o in zip((ref, other), opts):
            o.zero_grad()
            m(x).square().mean().backward()
            o.step()
    for a, b in zip(ref.parameters(), other.parameters()):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)


def test_make_optimizer_refuses_an_unknown_implementation():
    with pytest.raises(ValueError, match="optimizer implementation"):
        make_optimizer(resolve("madp", "cpu"), [torch.nn.Parameter(torch.zeros(1))], impl="turbo")


def test_cli_prints_the_table_and_writes_json(dataset, tmp_path):
    out = tmp_path / "bench.json"
    code, err = cli("bench", "train", "--models", "lpac", "--presets", "cpu", "--threads", "1", "--steps", "1",
                    "--warmup", "0", "--data", dataset, "--out", out)
    assert code == 0, err
    rows = json.loads(out.read_text())
    assert [(r["model"], r["preset"], r["threads"]) for r in rows] == [("lpac", "cpu", 1)]
    assert rows[0]["samples_per_s"] == pytest.approx(rows[0]["batch_size"] / rows[0]["step_s"])


@pytest.mark.parametrize("flag,value,named", [("--threads", "1,zero", "--threads"), ("--models", "madp,gpt", "--models"),
                                              ("--presets", "huge", "--presets")])
def test_cli_bad_lists_get_one_line(flag, value, named):
    code, err = cli("bench", "train", flag, value)
    assert code == 2 and named in err and len(err.strip().splitlines()) == 1


def test_cli_missing_dataset_gets_one_line(tmp_path):
    code, err = cli("bench", "train", "--data", tmp_path / "nothing")
    assert code == 2 and "manifest.json" in err and len(err.strip().splitlines()) == 1
