"""MADP's pieces against expectations computed without the code under test, and its wiring pinned
(issue 17: the mutation campaign found the sinusoidal embedding, the loss, the initialisation, the
packing of neighbourhoods and the model's wiring — RoPE, time embedding, padding — unchecked).

The last test is a characterization test: a tiny model, seeded, evaluated on fixed inputs, compared
with numbers stored in ``data/madp_golden.safetensors``. It fails on any change of the function the
model computes (a dropped RoPE, a flipped time-embedding sign, a lost padding mask, a changed init).
Regenerate the file only when such a change is intended, and say why in the commit::

    python -m tests.models.test_madp_contract --regenerate
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file

from madp.models import MADP
from madp.models.madp import TimestepEmbedding
from madp.models.packing import pack_rows

sys.path.insert(0, str(Path(__file__).parent))
from models_testutils import grid_positions, random_obs, tiny_madp_config  # noqa: E402


def swarm(gen, b: int, n: int, hi: float, lo: float = 0.0):
    """``obs [b, n, 4, 32, 32]`` then positions ``[b, n, 2]`` on a 1/64 m grid in [lo, hi]² m, drawn
    from ``gen`` in that order (the golden outputs depend on it)."""
    return random_obs(b, n, generator=gen), grid_positions(b * n, lo, hi, gen).view(b, n, 2)

GOLDEN = Path(__file__).parent / "data" / "madp_golden.safetensors"


def test_sinusoidal_embedding_is_the_transformer_formula():
    """Guards ``sinusoidal``: frequencies ``10000^(-i/half)``, ``sin`` then ``cos`` on the last axis."""
    emb = TimestepEmbedding(8, 16)
    k = torch.tensor([0, 1, 7, 1000])
    want = torch.tensor([[math.sin(kk * 10000.0 ** (-i / 4)) for i in range(4)]
                         + [math.cos(kk * 10000.0 ** (-i / 4)) for i in range(4)] for kk in k.tolist()])
    assert torch.allclose(emb.sinusoidal(k), want, atol=1e-4)
    with pytest.raises(ValueError, match="^time embedding dim must be even$"):
        TimestepEmbedding(7, 16)


def test_time_embedding_mlp_is_linear_leaky_relu_linear():
    """Guards the LeakyReLU between the two Linear layers and the dtype cast of the features."""
    emb = TimestepEmbedding(8, 4, leaky_slope=0.1).double()
    k = torch.tensor([3, 900])
    lin1, act, lin2 = emb.mlp
    assert isinstance(act, torch.nn.LeakyReLU) and act.negative_slope == 0.1
    h = emb.sinusoidal(k).double() @ lin1.weight.T + lin1.bias
    want = torch.where(h > 0, h, 0.1 * h) @ lin2.weight.T + lin2.bias
    got = emb(k)
    assert got.dtype == torch.float64 and torch.allclose(got, want)


@pytest.mark.parametrize(
    "sizes, row_len, rows, offsets",
    [
        ([3, 2, 4, 1, 5], 5, [0, 0, 1, 1, 2], [0, 3, 0, 4, 0]),  # exact fill (3 + 2 = 5) stays in the row
        ([5, 5], 5, [0, 1], [0, 0]),
        ([1, 1, 1], 8, [0, 0, 0], [0, 1, 2]),
        ([2, 7, 1], 8, [0, 1, 1], [0, 0, 7]),
    ],
)
def test_pack_rows_is_next_fit(sizes, row_len, rows, offsets):
    """Guards ``pack_rows``: next fit, a row filled exactly is not split, offsets restart at 0."""
    row, off = pack_rows(torch.tensor(sizes), row_len)
    assert row.tolist() == rows and off.tolist() == offsets
    assert row.dtype == torch.long and off.dtype == torch.long


def test_initialisation_is_nanogpt_style():
    """Guards ``_init_weights``: Linear weights N(0, 0.02), residual projections N(0, 0.02 / sqrt(2 L)),
    zero biases (L = encoder + decoder layers)."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config(d_model=64, n_enc_layers=3, n_dec_layers=3))
    residual = [m for m in model.modules() if getattr(m, "is_residual_proj", False)]
    plain = [m for m in model.modules() if isinstance(m, torch.nn.Linear) and not getattr(m, "is_residual_proj", False)]
    assert residual and plain
    res_w = torch.cat([m.weight.flatten() for m in residual])
    plain_w = torch.cat([m.weight.flatten() for m in plain])
    assert res_w.std().item() == pytest.approx(0.02 / math.sqrt(12), rel=0.05)
    assert plain_w.std().item() == pytest.approx(0.02, rel=0.05)
    assert all(m.bias is None or not m.bias.any() for m in residual + plain)


def test_loss_is_the_masked_mean_squared_noise_error(gen):
    """Guards ``loss``: ``(eps_hat - noise)^2`` averaged over valid robots and both action axes, with
    k and noise drawn from ``generator`` (k first, then noise)."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config()).eval()
    b, n = 2, 5
    obs, pos = swarm(gen, b, n, 300)
    act = torch.randn(b, n, 2, generator=gen)
    valid = torch.tensor([[True] * 5, [True, True, True, False, False]])
    g = torch.Generator().manual_seed(5)
    k = model.schedule.sample_timesteps(b, generator=g)
    noise = torch.randn(b, n, 2, generator=g)
    memory, mask = model.encode(obs, pos, valid)
    eps_hat = model.denoise(model.schedule.add_noise(act, noise, k), k, memory, pos, mask)
    err = (eps_hat - noise).square()
    want = (err[0].sum() + err[1, :3].sum()) / (8 * 2)
    with torch.no_grad():
        got = model(obs, pos, act, valid, torch.Generator().manual_seed(5))
        assert torch.allclose(got, want, rtol=1e-5)
        memory, mask = model.encode(obs, pos)
        eps_all = model.denoise(model.schedule.add_noise(act, noise, k), k, memory, pos, mask)
        assert torch.allclose(model.loss(obs, pos, act, None, k=k, noise=noise),
                              (eps_all - noise).square().mean(), rtol=1e-5)


def test_config_reaches_every_part():
    """Non-default settings reach the parts that use them (guards ``MADP.__init__`` dropping an
    argument, which the default config cannot tell apart: leaky slope of the CNN, the transformers and
    the time embedding, RoPE's tau, RoPE in how many layers, the schedule's beta range)."""
    cfg = tiny_madp_config(leaky_slope=0.2, rope_tau=300.0, rope_layers=2, beta_start=2e-4, beta_end=0.03)
    model = MADP(cfg)
    slopes = {m.negative_slope for m in model.modules() if isinstance(m, torch.nn.LeakyReLU)}
    assert slopes == {0.2}
    assert model.rope.tau == 300.0
    for stack in (model.encoder, model.decoder):
        assert [layer.use_rope for layer in stack.layers] == [True, True]
    assert (model.schedule.beta_start, model.schedule.beta_end) == (2e-4, 0.03)
    assert TimestepEmbedding(8, 4).mlp[1].negative_slope == 0.01  # the default slope


def test_a_float64_model_computes_in_float64(gen):
    """``model.double()`` takes float32 inputs and computes in float64 throughout, close to the float32
    model (guards every cast to the model's dtype: observations, actions, noise, RoPE, the bias)."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config()).eval()
    b, n = 2, 5
    obs, pos = swarm(gen, b, n, 400)
    act = torch.randn(b, n, 2, generator=gen)
    valid = torch.ones(b, n, dtype=torch.bool)
    valid[1, 4] = False
    u_k = torch.randn(b, n, 2, generator=gen)

    def outputs() -> dict:
        memory, mask = model.encode(obs, pos, valid)
        k, noise = torch.tensor([5, 600]), torch.randn(b, n, 2, generator=torch.Generator().manual_seed(1))
        return {
            "memory": memory,
            "eps": model.denoise(act, 7, memory, pos, mask, valid),
            "loss": model.loss(obs, pos, act, valid, k=k, noise=noise),
            "sample": model.sample(obs, pos, 3, 0.0, valid=valid, noise=u_k, sampler="dpm++"),
            "dec": model.sample_decentralized(obs[0], pos[0], 3, 0.0, noise=u_k[0], sampler="ddim"),
        }

    with torch.no_grad():
        want = outputs()
        model.double()
        got = outputs()
    for key in want:
        assert got[key].dtype == torch.float64, key
        assert torch.allclose(got[key].float(), want[key], atol=2e-4), key


def test_loss_draws_k_then_noise_in_the_models_dtype(gen):
    """With a generator, ``loss`` draws ``k [B]`` then the noise ``[B, N, 2]`` in the model's dtype (a
    float64 model draws float64 noise: another stream of numbers than float32)."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config()).double().eval()
    obs, pos = swarm(gen, 2, 4, 300)
    act = torch.randn(2, 4, 2, generator=gen)
    g = torch.Generator().manual_seed(4)
    k = model.schedule.sample_timesteps(2, generator=g)
    noise = torch.randn(2, 4, 2, generator=g, dtype=torch.float64)
    with torch.no_grad():
        assert torch.equal(model.loss(obs, pos, act, generator=torch.Generator().manual_seed(4)),
                           model.loss(obs, pos, act, k=k, noise=noise))


def test_a_float64_model_is_shift_invariant_to_float64_precision(gen):
    """RoPE depends on relative positions only, so moving the whole swarm by an exact offset leaves a
    float64 model's output unchanged to ~1e-12 — if RoPE's cos/sin reach it in float64 (guards
    ``self.rope(pos_m, self.dtype)`` losing its dtype: float32 tables move the output by ~1e-7)."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config(rope_layers=2)).double().eval()
    obs, pos = swarm(gen, 1, 8, 500, lo=100)
    shift = torch.tensor([123.0, -77.0])
    act = torch.randn(1, 8, 2, generator=gen)
    u_k = torch.randn(1, 8, 2, generator=gen)
    with torch.no_grad():
        def run(p):
            memory, mask = model.encode(obs, p)
            return (model.denoise(act, 40, memory, p, mask),
                    model.sample(obs, p, 3, 0.0, noise=u_k, sampler="dpm++"),
                    model.sample_decentralized(obs[0], p[0], 3, 0.0, noise=u_k[0], sampler="ddim"))
        # measured: 6e-17 (denoise), 6e-14 and 3e-14 (samples); with float32 tables 8e-12 and 3e-9
        for a, b, tol in zip(run(pos), run(pos + shift), (1e-13, 1e-10, 1e-10)):
            assert (a - b).abs().max() < tol


def test_training_and_sampling_paths_compute_the_same_eps(gen):
    """``denoise`` (what the loss trains) and the sampler's decoder (cached cross-attention K/V, additive
    mask bias, precomputed time embeddings) must be one function: one DDIM step from k = K to 0 returns
    x0_hat, from which eps_hat follows exactly. In float64 they agree to ~1e-13; a change to one path
    that the other lacks (mask, padding, time embedding, memory K/V) shows."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config(rope_layers=2)).double().eval()
    obs, pos = swarm(gen, 2, 6, 500)
    valid = torch.ones(2, 6, dtype=torch.bool)
    valid[1, 5] = False
    u_k = torch.randn(2, 6, 2, generator=gen, dtype=torch.float64)
    k = model.config.num_train_steps
    with torch.no_grad():
        x0 = model.sample(obs, pos, 1, 0.0, valid=valid, noise=u_k, sampler="ddim")
        memory, mask = model.encode(obs, pos, valid)
        eps = model.denoise(u_k, k, memory, pos, mask, valid)
    ab = model.schedule.alphas_cumprod[k]
    eps_from_sample = (u_k - ab.sqrt() * x0) / (1 - ab).sqrt()
    assert (eps_from_sample - eps)[valid].abs().max() < 1e-10


# ---------------------------------------------------------------- pinned wiring (characterization)


def _golden_outputs() -> dict[str, torch.Tensor]:
    torch.set_num_threads(1)
    out = {}
    gen = torch.Generator().manual_seed(2026)
    b, n = 2, 7
    obs, pos = swarm(gen, b, n, 420)  # r_c = 256: neighbourhoods, not one clique
    valid = torch.ones(b, n, dtype=torch.bool)
    valid[1, 5:] = False
    act = torch.randn(b, n, 2, generator=gen)
    for name, cfg in (("offset", tiny_madp_config()), ("nopos", tiny_madp_config(pos_token="none"))):
        torch.manual_seed(0)
        model = MADP(cfg).eval()
        with torch.no_grad():
            memory, mask = model.encode(obs, pos, valid)
            out[f"{name}.memory"] = memory
            out[f"{name}.eps"] = model.denoise(act, torch.tensor([3, 700]), memory, pos, mask, valid)
            out[f"{name}.eps_int_k"] = model.denoise(act, 250, memory, pos, mask, valid)
            out[f"{name}.loss"] = model(obs, pos, act, valid, torch.Generator().manual_seed(9)).reshape(1)
            out[f"{name}.loss_nomask"] = model(obs, pos, act, None, torch.Generator().manual_seed(9)).reshape(1)
            for sampler, eta in (("ddim", 0.5), ("dpm++", 0.0)):
                g = torch.Generator().manual_seed(11)
                out[f"{name}.sample.{sampler}"] = model.sample(obs, pos, 3, eta, g, valid, sampler=sampler)
                g = torch.Generator().manual_seed(11)
                out[f"{name}.dec.{sampler}"] = model.sample_decentralized(obs, pos, 3, eta, g, valid, sampler=sampler)
            out[f"{name}.clip"] = model.sample(obs, pos, 3, 0.0, torch.Generator().manual_seed(11), valid,
                                               sampler="ddim", clip_x0=0.3)
    return {k: v.detach().contiguous().float() for k, v in out.items()}


def test_model_function_is_pinned():
    """A seeded tiny model on fixed inputs computes the stored numbers (see the module docstring)."""
    want = load_file(GOLDEN)
    got = _golden_outputs()
    assert sorted(got) == sorted(want)
    for key in want:
        assert torch.allclose(got[key], want[key], rtol=1e-4, atol=1e-5), key


if __name__ == "__main__":
    if "--regenerate" not in sys.argv:
        sys.exit("usage: python -m tests.models.test_madp_contract --regenerate")
    GOLDEN.parent.mkdir(exist_ok=True)
    save_file(_golden_outputs(), str(GOLDEN))
    print(f"wrote {GOLDEN}")


def test_forward_is_loss_with_every_argument(gen):
    """Guards ``MADP.forward`` (what DDP calls): it passes ``k`` and ``noise`` through to ``loss``
    (mutants dropping either: a dropped ``k`` shifts ``noise`` into its place, a dropped ``noise``
    draws fresh noise)."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config()).eval()
    obs, pos = swarm(gen, 2, 4, 300)
    act = torch.randn(2, 4, 2, generator=gen)
    k = torch.tensor([3, 17])
    noise = torch.randn(2, 4, 2, generator=gen)
    with torch.no_grad():
        want = model.loss(obs, pos, act, None, None, k, noise)
        got = model(obs, pos, act, None, torch.Generator().manual_seed(9), k, noise)
        assert torch.equal(got, want)
        assert not torch.equal(model(obs, pos, act, None, None, k, -noise), want)


def test_padding_robots_never_reach_the_cnn(gen):
    """embed_tokens_5 (``valid`` not passed to ``apply_per_robot``: padding images run through the
    CNN). Padding never enters BatchNorm's batch statistics (``apply_per_robot``'s promise, which
    ``embed_tokens`` relies on): in training mode the valid robots' tokens, and the running
    statistics, do not depend on what the padding rows' observations hold."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config()).train()
    b, n = 2, 4
    obs, pos = swarm(gen, b, n, 300)
    valid = torch.tensor([[True, True, True, False], [True, True, False, False]])
    other = obs.clone()
    other[~valid] = 5.0 + 3.0 * torch.rand(int((~valid).sum()), 4, 32, 32, generator=gen)
    bn = next(m for m in model.cnn.modules() if isinstance(m, torch.nn.BatchNorm2d))
    stats = []
    tokens = []
    for o in (obs, other):
        bn.reset_running_stats()
        with torch.no_grad():
            mask = model.attention_mask(pos, valid)
            tokens.append(model.embed_tokens(o, pos, mask, valid))
        stats.append(bn.running_mean.clone())
    assert torch.equal(tokens[0], tokens[1]) and torch.equal(stats[0], stats[1])
    assert (tokens[0][~valid] == 0).all() and (tokens[0][valid] != 0).any()


def test_pack_rows_of_no_items_is_two_empty_long_tensors():
    """pack_rows_16 / _19 / _22 / _25 (``dtype=torch.long`` dropped or None: ``torch.tensor([])`` is
    float32). ``(row [U], offset [U])`` are long for every U, U = 0 included, so they can index."""
    row, off = pack_rows(torch.zeros(0, dtype=torch.long), 4)
    assert row.dtype == torch.long and off.dtype == torch.long and row.shape == off.shape == (0,)
    assert torch.arange(3)[row].shape == (0,)
