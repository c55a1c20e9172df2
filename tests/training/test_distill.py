"""``madp train --distill``: a student that does in one sampler step what its teacher does in S."""

import json
from dataclasses import replace

import pytest
import torch

from madp.errors import SettingError
from madp.models import MADP, madp_config
from madp.models.diffusion import DDPMSchedule
from madp.training import load_policy, resolve, train
from tests.conftest import tiny_dataset
from tests.test_reliability_errors import cli


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return tiny_dataset(tmp_path_factory, "distill-data")


@pytest.fixture(scope="module")
def teacher():
    """The shipped MADP: a teacher whose samples are those of a trained policy."""
    from madp.policies.checkpoint import shipped_checkpoint

    return shipped_checkpoint("madp")


def _state(n=5, b=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(b, n, 4, 32, 32, generator=g), torch.rand(b, n, 2, generator=g) * 300, \
        torch.randn(b, n, 2, generator=g)


def test_predict_eps_inverts_predict_x0():
    s = DDPMSchedule()
    x0, eps = torch.randn(3, 4, 2, dtype=torch.float64), torch.randn(3, 4, 2, dtype=torch.float64)
    k = torch.tensor([1, 500, 1000])
    x_k = s.add_noise(x0, eps, k)
    assert torch.allclose(s.predict_eps(x_k, x0, k), eps, atol=1e-9)
    assert torch.allclose(s.predict_x0(x_k, s.predict_eps(x_k, x0, k), k), x0, atol=1e-6)


@pytest.mark.parametrize("sampler", ["dpm++", "ddim"])
def test_a_sample_model_samples_its_prediction_in_one_step(sampler):
    """With S = 1 every sampler lands on the sample the head predicts from the noise at step K, in
    the centralized and the decentralized form (fails if the noise derived from it were wrong)."""
    torch.manual_seed(0)
    model = MADP(madp_config("cpu", prediction="sample")).eval()
    obs, pos, noise = _state()
    with torch.no_grad():
        memory, mask = model.encode(obs, pos)
        rope = model.rope(pos, model.dtype)
        predicted = model._head_out(noise, 1000, model.decoder.memory_kv(memory, rope), rope, mask)
        u = model.sample(obs, pos, 1, noise=noise, sampler=sampler)
    assert torch.allclose(u, predicted, atol=1e-4)
    assert predicted.abs().max() > 0.01
    near = torch.zeros(1, 3, 2)  # one fully connected swarm: decentralized = centralized
    obs1, _, noise1 = _state(n=3, b=1, seed=1)
    u_c = model.sample(obs1, near + torch.tensor([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]), 1, noise=noise1,
                       sampler=sampler)
    u_d = model.sample_decentralized(obs1, near + torch.tensor([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]), 1,
                                     noise=noise1, sampler=sampler)
    assert torch.allclose(u_c, u_d, atol=1e-4)


def test_one_step_loss_needs_a_sample_model():
    model = MADP(madp_config("cpu"))
    obs, pos, noise = _state()
    with pytest.raises(ValueError, match="predicts the sample"):
        model.one_step_loss(obs, pos, noise, noise)


def _gap(student, teacher, obs, pos, noise) -> float:
    """Mean squared gap between the student's one-step and the teacher's three-step samples."""
    with torch.no_grad():
        return float((student.sample(obs, pos, 1, noise=noise) - teacher.sample(obs, pos, 3, noise=noise))
                     .square().mean())


def test_distillation_brings_the_one_step_student_to_the_teacher(dataset, teacher, tmp_path):
    """The student starts as the teacher (same weights, its head now read as the sample, so far
    off) and ends much closer to the teacher's S = 3 samples from the same noise; the policy file
    predicts the sample, keeps the teacher's action statistics and records its teacher."""
    from madp.data_schema.dataset import open_dataset
    from madp.training import ShardStream
    from madp.training.stream import collate_swarms

    run = tmp_path / "student"
    train(resolve("madp", "cpu", data=str(dataset), out=str(run), epochs=3, batch_size=8, num_workers=0,
                  val_samples=16, seed=4, lr=1e-3, warmup_steps=0, distill=str(teacher)), progress=False)
    t_model, t_meta = load_policy(teacher)
    s_model, s_meta = load_policy(run / "checkpoints" / "latest" / "policy.safetensors")
    assert s_model.config.prediction == "sample" and t_model.config.prediction == "epsilon"
    assert s_meta["distill"]["sampling_steps"] == 3 and len(s_meta["distill"]["sha256"]) == 64
    assert torch.equal(s_model.action_mean, t_model.action_mean) and torch.equal(s_model.action_std, t_model.action_std)
    assert s_meta["action_stats"]["std"] == t_model.action_std.tolist()
    start = MADP(replace(t_model.config, prediction="sample")).eval()
    start.load_state_dict(t_model.state_dict())
    m = open_dataset(dataset)
    batch = collate_swarms(list(ShardStream(dataset, m, "val", seed=1, batch_size=1, buffer_size=1))[:16])
    noise = torch.randn(batch["pos_m"].shape, generator=torch.Generator().manual_seed(9))
    before = _gap(start, t_model, batch["obs"], batch["pos_m"], noise)
    after = _gap(s_model, t_model, batch["obs"], batch["pos_m"], noise)
    assert after < 0.3 * before, (before, after)
    lines = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    val = [x["val_loss"] for x in lines if "val_loss" in x]
    assert val[-1] < val[0]


def test_distillation_resumes_exactly(dataset, teacher, tmp_path):
    kw = dict(data=str(dataset), epochs=1, batch_size=8, num_workers=0, log_every=1, val_samples=8,
              checkpoint_every=2, seed=5, distill=str(teacher))
    train(resolve("madp", "cpu", out=str(tmp_path / "full"), **kw), progress=False)
    train(resolve("madp", "cpu", out=str(tmp_path / "part"), stop_after_steps=4, **kw), progress=False)
    train(resolve("madp", "cpu", out=str(tmp_path / "part"), **kw), resume=True, progress=False)

    def losses(run):
        return [json.loads(x).get("loss") for x in (run / "metrics.jsonl").read_text().splitlines()]

    assert losses(tmp_path / "full") == losses(tmp_path / "part")


def test_distill_refuses_what_it_cannot_learn_from(dataset, teacher, tmp_path):
    with pytest.raises(SettingError, match="^distill: only MADP"):
        resolve("lpac", "cpu", distill=str(teacher))
    lpac_run = tmp_path / "lpac"
    train(resolve("lpac", "cpu", data=str(dataset), out=str(lpac_run), epochs=1, batch_size=8, num_workers=0,
                  val_samples=8, max_steps_per_epoch=1), progress=False)
    code, err = cli("train", "--data", dataset, "--out", tmp_path / "s1", "--distill",
                    lpac_run / "checkpoints" / "latest" / "policy.safetensors")
    assert code != 0 and "distill needs an MADP checkpoint" in err and len(err.strip().splitlines()) == 1
    code, err = cli("train", "--data", dataset, "--out", tmp_path / "s2", "--distill", tmp_path / "missing.safetensors")
    assert code != 0 and "missing.safetensors" in err and len(err.strip().splitlines()) == 1


def test_a_one_step_student_refuses_more_sampler_steps(tmp_path):
    """Trained at step K alone, the student would sample nonsense at S = 3 (the evaluation
    default): the policy and the export refuse it in one line naming --sampling-steps."""
    from madp.export.onnx import export_policy
    from madp.policies import MADPPolicy, SamplingSettings
    from madp.training.checkpoint import save_policy

    model = MADP(madp_config("cpu", prediction="sample"))
    with pytest.raises(SettingError, match="^sampling_steps: .*distilled into one sampler step.*got 3"):
        MADPPolicy(model, sampling=SamplingSettings())
    MADPPolicy(model, sampling=SamplingSettings(sampling_steps=1))
    path = tmp_path / "student.safetensors"
    save_policy(path, model, "madp", {"action_stats": {"count": 1, "mean": [0.0, 0.0], "std": [1.0, 1.0]}})
    with pytest.raises(SettingError, match="--sampling-steps 1"):
        export_policy(path, tmp_path / "export")
    assert not (tmp_path / "export").exists()
    export_policy(path, tmp_path / "export1", SamplingSettings(sampling_steps=1))
