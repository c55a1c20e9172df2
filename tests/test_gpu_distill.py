"""scripts/gpu_distill.sh end to end on the CPU at tiny sizes (no GPU): what comes back fits the GPU
machine's return channel, and the student is a one-step policy distilled from the shipped MADP."""

import sys
import tarfile

import pytest

from madp.io.checksum import sha256_file
from madp.policies import shipped_checkpoint
from madp.training.checkpoint import load_policy
from tests.conftest import REPO, returned_files, run_script, script_results

SCRIPT = REPO / "scripts" / "gpu_distill.sh"
TINY = ["--python", sys.executable, "--minutes", "0.5", "--steps", "8", "--batch", "4", "--scale", "0.001",
        "--workers", "0"]


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return script_results(tmp_path_factory, SCRIPT, *TINY)


def test_the_student_comes_back_within_the_limits_and_names_its_teacher(results):
    out = results / "out"
    files = returned_files(out)
    assert files == ["device.txt", "logs.tar.gz", "metrics.jsonl", "stages.tsv", "student.safetensors",
                     "train-config.json"]
    stages = [line.split("\t") for line in (out / "stages.tsv").read_text().splitlines()]
    assert [s[0] for s in stages] == ["data-uniform", "data-narrow", "data-packed", "data-n128", "data-deployed", "train"]
    assert "--policy madp/checkpoints/madp-cpu.safetensors --select explore" in stages[4][2]
    model, meta = load_policy(out / "student.safetensors")
    teacher = shipped_checkpoint("madp")
    assert model.config.prediction == "sample" and meta["step"] == 8
    assert meta["distill"]["sha256"] == sha256_file(teacher) and meta["distill"]["sampling_steps"] == 3
    assert len(meta["dataset"]["more"]) == 4
    with tarfile.open(out / "logs.tar.gz") as tar:
        assert {f"logs/{s[0]}.log" for s in stages} <= set(tar.getnames())


def test_bad_flags_and_used_directories_stop_at_once(tmp_path):
    r = run_script(SCRIPT, tmp_path / "o", "--bogus", "1", timeout=60)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "gpu_distill.sh: error: unknown flag --bogus (see the header of scripts/gpu_distill.sh)"]
    r = run_script(SCRIPT, tmp_path / "o", "--minutes", timeout=60)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == ["gpu_distill.sh: error: --minutes needs a value"]
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "f").write_text("x")
    r = run_script(SCRIPT, tmp_path / "used", timeout=60)
    assert r.returncode == 2 and "not empty" in r.stderr
    r = run_script(SCRIPT, tmp_path / "o2", "--work", tmp_path / "used", timeout=60)
    assert r.returncode == 2 and "did not write" in r.stderr and (tmp_path / "used" / "f").exists()
