"""scripts/gpu_paper.sh end to end on the CPU at tiny sizes (no install, no GPU): what comes back fits
the limits of the GPU machine's return channel and the float16 parts load into the trained policy."""

import hashlib
import json
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest
import torch

from madp.training.checkpoint import load_policy
from tests.conftest import REPO, returned_files, run_script, script_results
from tests.guides import first_commands

SCRIPT = REPO / "scripts" / "gpu_paper.sh"
TINY = ["--python", sys.executable, "--device", "cpu", "--no-cuda-tests",
        "--n", "160", "--datagen-workers", "1",
        "--datagen-args", "--world-size 256 --num-robots 4 --num-features 4 --samples-per-shard 16",
        "--preset", "cpu", "--batch-size", "4", "--train-minutes", "0", "--train-steps", "2", "--train-workers", "0",
        "--train-args", "--val-samples 8", "--eval-envs", "2", "--eval-steps", "3", "--eval-workers", "1",
        "--bench-presets", "cpu", "--bench-grid", "dpm++:3", "--bench-repeats", "1", "--part-mib", "0.25"]


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return script_results(tmp_path_factory, SCRIPT, *TINY)


def test_the_gpu_guide_opens_with_the_script_these_tests_run():
    """docs/guides/gpu.md's first command is this script, which ``results`` runs at tiny sizes (on this
    interpreter: installing is the one step it leaves out)."""
    assert first_commands(REPO / "docs" / "guides" / "gpu.md") == [f"bash {SCRIPT.relative_to(REPO)} results/"]


def test_results_fit_the_return_limits_and_record_the_run(results):
    out = results / "out"
    files = returned_files(out)
    parts = [f for f in files if f.startswith("policy-fp16.safetensors.0")]
    assert files == ["outputs.tar.gz", *parts, "policy-fp16.safetensors.parts.json", "provenance.json"]
    assert len(parts) >= 2  # --part-mib 0.25 splits the cpu preset's ~0.6 MB
    prov = json.loads((out / "provenance.json").read_text())
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    assert prov["commit"] == (head or None) and prov["failed_stage"] is None and prov["eval_device"] == "cpu"
    assert [s["name"] for s in prov["stages"]] == ["preflight", "datagen", "train", "fp16", "eval", "bench"]
    assert all(s["exit"] == 0 and s["seconds"] >= 0 for s in prov["stages"])
    assert prov["stages"][2]["command"].startswith("madp train --model madp --preset cpu")
    for suite in ("uniform", "cities"):
        assert prov["figures"][suite]["madp"]["n"] == 2 and 0 < prov["figures"][suite]["madp"]["mean"] < 2
    assert {(x["mode"], x["sampler"], x["num_steps"]) for x in prov["latency"]} == {
        (m, s, k) for m in ("decentralized", "centralized") for s, k in (("ddim", 50), ("dpm++", 3))}
    for name, rec in prov["files"].items():
        data = (out / name).read_bytes()
        assert rec == {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    with tarfile.open(out / "outputs.tar.gz") as tar:
        names = {n.lstrip("./") for n in tar.getnames()}
        assert {"train/metrics.jsonl", "train/config.json", "data/manifest.json", "bench-infer.json",
                "eval/uniform/summary.json", "eval/uniform/summary.md", "eval/uniform/config.json",
                "eval/cities/summary.json", "eval/cities/results.parquet", "logs/stages.tsv", "logs/train.log"} <= names
        cfg = json.load(tar.extractfile("./eval/uniform/config.json"))
    assert cfg["device"] == "cpu" and cfg["checkpoints"]["madp"]["path"].endswith("policy-fp16.safetensors.parts.json")


def test_the_parts_load_as_the_trained_policy_in_float16(results):
    trained, meta = load_policy(results / "work" / "train" / "checkpoints" / "latest" / "policy.safetensors")
    params = {k for k, _ in trained.named_parameters()}
    for path in ("policy-fp16.safetensors.parts.json", "policy-fp16.safetensors.000"):
        shipped, smeta = load_policy(results / "out" / path)
        assert smeta["step"] == meta["step"] == 2 and smeta["weights_dtype"] == "float16"
        for k, v in trained.state_dict().items():
            got = shipped.state_dict()[k]
            assert got.dtype == v.dtype
            assert torch.equal(got, v.half().float() if k in params else v), k  # fp16 rounding only


def test_bad_flags_and_a_used_results_dir_stop_at_once(tmp_path):
    r = run_script(SCRIPT, tmp_path / "r", "--bogus", timeout=60)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == ["gpu_paper.sh: error: unknown flag --bogus (see the header of scripts/gpu_paper.sh)"]
    r = run_script(SCRIPT, tmp_path / "r", "--train-minutes", "x", timeout=60)
    assert r.returncode == 2 and "--train-minutes" in r.stderr
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "f").write_text("x")
    r = run_script(SCRIPT, tmp_path / "used", timeout=60)
    assert r.returncode == 2 and "not empty" in r.stderr


def test_a_failing_stage_is_named_and_its_logs_come_back(tmp_path):
    args = [a if a != "--world-size 256 --num-robots 4 --num-features 4 --samples-per-shard 16" else "--num-robots 0"
            for a in TINY]
    r = run_script(SCRIPT, tmp_path / "res", "--work", tmp_path / "work", *args)
    assert r.returncode == 1
    assert "stage 'datagen' failed" in r.stderr
    prov = json.loads((tmp_path / "res" / "provenance.json").read_text())
    assert prov["failed_stage"] == "datagen" and prov["stages"][-1]["exit"] != 0
    with tarfile.open(tmp_path / "res" / "outputs.tar.gz") as tar:
        assert "--num-robots" in tar.extractfile("./logs/datagen.log").read().decode()
    assert sorted(p.name for p in Path(tmp_path / "res").iterdir()) == ["outputs.tar.gz", "provenance.json"]
