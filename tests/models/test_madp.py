"""MADP (``madp.models.madp``): shapes, loss, equivariance and invariance, masks and padding,
decentralized against centralized sampling, round trips; then its pieces against expectations
computed without the code under test, and its wiring pinned (the mutation campaign found
the sinusoidal embedding, the loss, the initialisation and the model's wiring — RoPE, time embedding,
padding — unchecked; each such test names the mutants it guards).

``test_model_function_is_pinned`` is a characterization test: a tiny model, seeded, evaluated on
fixed inputs, compared with numbers stored in ``data/madp_golden.safetensors``. It fails on any
change of the function the model computes (a dropped RoPE, a flipped time-embedding sign, a lost
padding mask, a changed init). Regenerate the file only when such a change is intended, and say why
in the commit::

    python -m tests.models.test_madp --regenerate
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

from .models_testutils import grid_positions, random_obs, tiny_madp_config


def eps_hat(model, obs, pos, x, k, valid=None):
    memory, mask = model.encode(obs, pos, valid)
    return model.denoise(x, k, memory, pos, mask, valid)


def swarm(gen, b=2, n=8, low=200.0, high=500.0):
    obs = random_obs(b, n, generator=gen)
    pos = torch.stack([grid_positions(n, low, high, gen) for _ in range(b)])
    x = torch.randn(b, n, 2, generator=gen)
    k = torch.randint(1, 1001, (b,), generator=gen)
    return obs, pos, x, k


def test_shapes_loss_and_gradients(gen):
    torch.manual_seed(0)
    model = MADP(tiny_madp_config()).train()
    obs, pos, x, _ = swarm(gen)
    loss = model(obs, pos, x)
    assert loss.ndim == 0 and torch.isfinite(loss)
    loss.backward()
    no_grad = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert no_grad == []
    model.eval()
    memory, mask = model.encode(obs, pos)
    assert memory.shape == (2, 8, 32) and mask.shape == (2, 8, 8)
    assert model.denoise(x, 7, memory, pos, mask).shape == (2, 8, 2)


def test_loss_ignores_padding(tiny_madp, gen):
    obs, pos, x, k = swarm(gen)
    valid = torch.ones(2, 8, dtype=torch.bool)
    valid[1, 5:] = False
    noise = torch.randn(2, 8, 2, generator=gen)
    l1 = tiny_madp.loss(obs, pos, x, valid, k=k, noise=noise)
    obs2, pos2, x2 = obs.clone(), pos.clone(), x.clone()
    obs2[1, 5:] = 9.0
    pos2[1, 5:] = pos[1, 0]          # padding on top of a real robot: still ignored
    x2[1, 5:] = 100.0
    l2 = tiny_madp.loss(obs2, pos2, x2, valid, k=k, noise=noise)
    assert torch.allclose(l1, l2, atol=1e-6)


def test_permutation_equivariance(tiny_madp, gen):
    obs, pos, x, k = swarm(gen, n=10, low=0.0, high=600.0)
    out = eps_hat(tiny_madp, obs, pos, x, k)
    perm = torch.randperm(10, generator=gen)
    out_p = eps_hat(tiny_madp, obs[:, perm], pos[:, perm], x[:, perm], k)
    assert torch.allclose(out_p, out[:, perm], atol=1e-5)


def test_common_shift_invariance(tiny_madp, gen):
    obs, pos, x, k = swarm(gen, n=10, low=100.0, high=600.0)
    out = eps_hat(tiny_madp, obs, pos, x, k)
    shifted = pos + torch.tensor([123.0, -77.0])  # exact in float32 on the 1/64 m grid
    assert torch.equal(shifted - torch.tensor([123.0, -77.0]), pos)
    out_s = eps_hat(tiny_madp, obs, shifted, x, k)
    assert torch.allclose(out_s, out, atol=1e-5)
    # not trivially invariant: a non-rigid change of positions does change the output
    out_d = eps_hat(tiny_madp, obs, pos * 1.2, x, k)
    assert (out_d - out).abs().max() > 1e-4


def test_robots_outside_the_mask_have_no_influence(tiny_madp, gen):
    n_group, n_far = 6, 4
    obs = random_obs(1, n_group + n_far, generator=gen)
    group = grid_positions(n_group, 100.0, 250.0, gen)
    far = grid_positions(n_far, 700.0, 900.0, gen)   # > 256 m from every group robot
    pos = torch.cat([group, far])[None]
    x = torch.randn(1, n_group + n_far, 2, generator=gen)
    k = torch.tensor([300])
    out = eps_hat(tiny_madp, obs, pos, x, k)

    obs2, pos2, x2 = obs.clone(), pos.clone(), x.clone()
    obs2[0, n_group:] = torch.rand(n_far, 4, 32, 32, generator=gen)
    pos2[0, n_group:] = grid_positions(n_far, 650.0, 1000.0, gen)
    x2[0, n_group:] = torch.randn(n_far, 2, generator=gen)
    out2 = eps_hat(tiny_madp, obs2, pos2, x2, k)
    assert torch.allclose(out2[0, :n_group], out[0, :n_group], atol=1e-6)
    assert (out2[0, n_group:] - out[0, n_group:]).abs().max() > 1e-5

    # positive control: changing a robot inside the group's range changes the group
    obs3 = obs.clone()
    obs3[0, 0] = torch.rand(4, 32, 32, generator=gen)
    out3 = eps_hat(tiny_madp, obs3, pos, x, k)
    assert (out3[0, 1:n_group] - out[0, 1:n_group]).abs().max() > 1e-5


def test_decentralized_ignores_two_hop_observations_centralized_does_not(tiny_madp, gen):
    # chain A - B - C: 200 m apart, so A and C are 400 m apart (outside each other's mask)
    pos = torch.tensor([[100.0, 500.0], [300.0, 500.0], [500.0, 500.0]])
    obs = random_obs(3, generator=gen)
    obs2 = obs.clone()
    obs2[2] = torch.rand(4, 32, 32, generator=gen)
    noise = torch.randn(3, 2, generator=gen)

    dec1 = tiny_madp.sample_decentralized(obs, pos, num_steps=10, noise=noise)
    dec2 = tiny_madp.sample_decentralized(obs2, pos, num_steps=10, noise=noise)
    assert torch.allclose(dec1[0], dec2[0], atol=1e-6)     # A never sees C's observation
    assert (dec1[1] - dec2[1]).abs().max() > 1e-4          # B does

    cen1 = tiny_madp.sample(obs[None], pos[None], num_steps=10, noise=noise[None])[0]
    cen2 = tiny_madp.sample(obs2[None], pos[None], num_steps=10, noise=noise[None])[0]
    assert (cen1[0] - cen2[0]).abs().max() > 1e-4          # two layers carry C -> B -> A


def test_padding_does_not_change_real_robots(tiny_madp, gen):
    obs, pos, x, k = swarm(gen, b=1, n=5)
    out = eps_hat(tiny_madp, obs, pos, x, k)
    pad = 3
    obs_p = torch.cat([obs, torch.rand(1, pad, 4, 32, 32, generator=gen)], 1)
    pos_p = torch.cat([pos, pos[:, :pad] + 1.0], 1)       # padding placed among the real robots
    x_p = torch.cat([x, torch.randn(1, pad, 2, generator=gen)], 1)
    valid = torch.tensor([[True] * 5 + [False] * pad])
    out_p = eps_hat(tiny_madp, obs_p, pos_p, x_p, k, valid)
    assert torch.allclose(out_p[:, :5], out, atol=1e-5)
    assert torch.equal(out_p[:, 5:], torch.zeros(1, pad, 2))
    # batches mixing team sizes
    a = tiny_madp.sample(obs_p, pos_p, num_steps=5, valid=valid, noise=x_p)
    b = tiny_madp.sample(obs, pos, num_steps=5, noise=x)
    assert torch.allclose(a[:, :5], b, atol=1e-5)


@pytest.mark.parametrize("sampler,eta", [("ddim", 0.0), ("ddim", 0.7), ("dpm++", 0.0)])
def test_decentralized_equals_centralized_when_everyone_sees_everyone(tiny_madp, gen, sampler, eta):
    n = 7
    obs = random_obs(n, generator=gen)
    pos = grid_positions(n, 400.0, 550.0, gen)   # diameter < 256 m: one full neighbourhood
    assert tiny_madp.attention_mask(pos[None]).all()
    cen = tiny_madp.sample(obs[None], pos[None], num_steps=20, eta=eta, sampler=sampler,
                           generator=torch.Generator().manual_seed(5))[0]
    dec = tiny_madp.sample_decentralized(obs, pos, num_steps=20, eta=eta, sampler=sampler,
                                         generator=torch.Generator().manual_seed(5))
    assert torch.allclose(dec, cen, atol=1e-4)


def test_decentralized_equals_centralized_for_separate_cliques(tiny_madp, gen):
    """Two far-apart clusters, each fully connected: every neighbourhood is a whole component."""
    b, n = 2, 8
    obs = random_obs(b, n, generator=gen)
    pos = torch.stack([torch.cat([grid_positions(4, 50.0, 200.0, gen), grid_positions(4, 700.0, 850.0, gen)])
                       for _ in range(b)])
    noise = torch.randn(b, n, 2, generator=gen)
    cen = tiny_madp.sample(obs, pos, num_steps=10, noise=noise)
    dec = tiny_madp.sample_decentralized(obs, pos, num_steps=10, noise=noise)
    assert torch.allclose(dec, cen, atol=1e-4)


def test_decentralized_batched_with_padding(tiny_madp, gen):
    obs = random_obs(2, 6, generator=gen)
    pos = torch.stack([grid_positions(6, 0.0, 1024.0, gen) for _ in range(2)])
    valid = torch.tensor([[True] * 6, [True] * 4 + [False] * 2])
    noise = torch.randn(2, 6, 2, generator=gen)
    both = tiny_madp.sample_decentralized(obs, pos, num_steps=5, valid=valid, noise=noise)
    first = tiny_madp.sample_decentralized(obs[0], pos[0], num_steps=5, noise=noise[0])
    second = tiny_madp.sample_decentralized(obs[1, :4], pos[1, :4], num_steps=5, noise=noise[1, :4])
    assert torch.allclose(both[0], first, atol=1e-5)
    assert torch.allclose(both[1, :4], second, atol=1e-5)
    assert torch.equal(both[1, 4:], torch.zeros(2, 2))
    ind = tiny_madp.sample_decentralized(obs, pos, num_steps=5, eta=1.0, sampler="ddim", valid=valid,
                                         independent_noise=True,
                                         generator=torch.Generator().manual_seed(0))
    assert torch.isfinite(ind).all()


def test_sampling_is_reproducible_and_eta_one_runs(tiny_madp, gen):
    obs, pos, _, _ = swarm(gen)
    a = tiny_madp.sample(obs, pos, num_steps=8, generator=torch.Generator().manual_seed(3))
    b = tiny_madp.sample(obs, pos, num_steps=8, generator=torch.Generator().manual_seed(3))
    assert a.shape == (2, 8, 2) and torch.equal(a, b)
    c = tiny_madp.sample(obs, pos, num_steps=8, eta=1.0, sampler="ddim", generator=torch.Generator().manual_seed(3))
    d = tiny_madp.sample(obs, pos, num_steps=8, eta=1.0, sampler="ddim", generator=torch.Generator().manual_seed(4))
    assert torch.isfinite(c).all() and not torch.allclose(c, d)


def test_action_normalisation_round_trip(tiny_madp):
    tiny_madp.set_action_stats(torch.tensor([0.5, -0.2]), torch.tensor([2.0, 3.0]))
    u = torch.randn(3, 4, 2)
    assert torch.allclose(tiny_madp.denormalize_actions(tiny_madp.normalize_actions(u)), u, atol=1e-6)
    assert "action_mean" in tiny_madp.state_dict() and "action_std" in tiny_madp.state_dict()


def test_state_dict_round_trip_through_safetensors(tmp_path, gen):
    torch.manual_seed(0)
    cfg = tiny_madp_config()
    model = MADP(cfg)
    model.train()
    obs, pos, x, k = swarm(gen)
    model(obs, pos, x)  # move BatchNorm running stats away from their init
    model.set_action_stats(torch.tensor([0.1, 0.2]), torch.tensor([1.5, 2.5]))
    model.eval()
    path = tmp_path / "madp.safetensors"
    save_file(model.state_dict(), str(path), metadata={"config": str(cfg.to_dict())})
    torch.manual_seed(1)
    clone = MADP(type(cfg).from_dict(cfg.to_dict()))
    clone.load_state_dict(load_file(str(path)))
    clone.eval()
    assert torch.equal(clone.action_std, model.action_std)
    assert torch.equal(eps_hat(clone, obs, pos, x, k), eps_hat(model, obs, pos, x, k))


@pytest.mark.parametrize("sampler,eta", [("ddim", 0.0), ("ddim", 0.5), ("dpm++", 0.0)])
def test_decentralized_dedupe_matches_per_robot_computation(tiny_madp, gen, sampler, eta):
    obs = random_obs(2, 12, generator=gen)
    pos = torch.stack([torch.cat([grid_positions(6, 100.0, 250.0, gen), grid_positions(6, 200.0, 900.0, gen)])
                       for _ in range(2)])
    valid = torch.ones(2, 12, dtype=torch.bool)
    valid[1, -3:] = False
    a = tiny_madp.sample_decentralized(obs, pos, num_steps=10, eta=eta, valid=valid, dedupe=True, sampler=sampler,
                                       generator=torch.Generator().manual_seed(9))
    b = tiny_madp.sample_decentralized(obs, pos, num_steps=10, eta=eta, valid=valid, dedupe=False, sampler=sampler,
                                       generator=torch.Generator().manual_seed(9))
    assert torch.allclose(a, b, atol=1e-5)


@pytest.mark.parametrize("decentralized", [True, False])
@pytest.mark.parametrize("sampler,eta", [("ddim", 0.5), ("dpm++", 0.0)])
def test_copies_encode_once_and_equal_sampling_repeated_states(tiny_madp, gen, decentralized, sampler, eta):
    """``copies=C``: C samples of every state, row b·C + c, the same as sampling C repeated states with the
    same noise (padding and several neighbourhoods included); the encoder sees only the B states."""
    c = 3
    obs = random_obs(2, 12, generator=gen)
    pos = torch.stack([torch.cat([grid_positions(6, 100.0, 250.0, gen), grid_positions(6, 200.0, 900.0, gen)])
                       for _ in range(2)])
    valid = torch.ones(2, 12, dtype=torch.bool)
    valid[1, -3:] = False
    noise, step_noise = torch.randn(2 * c, 12, 2, generator=gen), torch.randn(4, 2 * c, 12, 2, generator=gen)
    fn = tiny_madp.sample_decentralized if decentralized else tiny_madp.sample
    kw = dict(num_steps=4, eta=eta, sampler=sampler, noise=noise, step_noise=step_noise if eta else None)
    encoded = []  # rows through the encoder per call
    hook = tiny_madp.encoder.register_forward_hook(lambda mod, args, out: encoded.append(out.shape[0]))
    try:
        once = fn(obs, pos, valid=valid, copies=c, **kw)
        repeated = fn(obs.repeat_interleave(c, 0), pos.repeat_interleave(c, 0), valid=valid.repeat_interleave(c, 0),
                      **kw)
    finally:
        hook.remove()
    assert once.shape == (2 * c, 12, 2) and torch.allclose(once, repeated, atol=1e-5)
    assert not torch.allclose(once[0], once[1])  # the copies differ by their noise
    assert torch.equal(once[c:, -3:], torch.zeros(c, 3, 2))  # padding robots of every copy
    assert encoded[1] >= c * encoded[0]  # repeated states are encoded C times; copies once


@pytest.mark.parametrize("sampler", ["ddim", "dpm++"])
def test_decentralized_equals_each_robot_running_the_model_on_its_own_neighbourhood(tiny_madp, gen, sampler):
    """The reference of the paper's decentralized execution, one robot at a time: robot i takes the
    tokens its neighbours computed for themselves, runs encoder and sampler on just its
    neighbourhood (mask recomputed among those robots, with the component term) and keeps its own
    action. Overlapping, unequal neighbourhoods, two swarms, padding. Fails if packed
    neighbourhoods see each other, if an ego reads another slot, or if noise is not shared; and
    on full attention inside each neighbourhood: several neighbourhoods here hold two
    robots more than r_c apart, which must not attend to each other."""
    b, n = 2, 10
    obs = random_obs(b, n, generator=gen)
    pos = torch.stack([grid_positions(n, 0.0, 700.0, gen) for _ in range(b)])
    valid = torch.ones(b, n, dtype=torch.bool)
    valid[1, -2:] = False
    noise = torch.randn(b, n, 2, generator=gen)
    got = tiny_madp.sample_decentralized(obs, pos, num_steps=6, valid=valid, noise=noise, sampler=sampler)
    mask = tiny_madp.attention_mask(pos, valid)
    tokens = tiny_madp.embed_tokens(obs, pos, mask, valid)
    sizes, not_cliques = set(), 0
    for s in range(b):
        for i in range(int(valid[s].sum())):
            hood = mask[s, i].nonzero().flatten()
            sizes.add(len(hood))
            not_cliques += not bool(mask[s][hood][:, hood].all())
            p = pos[s, hood][None]
            m = tiny_madp.attention_mask(p)
            memory = tiny_madp.encode_tokens(tokens[s, hood][None], p, m)
            x = tiny_madp._sample_loop(memory, p, m, noise[s, hood][None], tiny_madp.make_sampler(sampler, 6), None)
            own = int((hood == i).nonzero())
            assert torch.allclose(got[s, i], x[0, own], atol=1e-5), (s, i)
    assert len(sizes) > 2  # neighbourhoods of several sizes, so they overlap without being equal
    assert not_cliques >= 3  # and not whole connected groups: the packed mask must still cut pairs > r_c
    assert torch.equal(got[1, -2:], torch.zeros(2, 2))


def test_paper_preset_structure():
    from madp.models import madp_config

    model = MADP(madp_config("paper"))
    assert model.cnn.flat_dim == 32 * 26 * 26 and model.cnn.linear.out_features == 32
    assert model.token_proj.in_features == 34 and model.token_proj.out_features == 256
    assert len(model.encoder.layers) == 8 and len(model.decoder.layers) == 8
    assert [layer.use_rope for layer in model.encoder.layers] == [True] + [False] * 7
    assert [layer.use_rope for layer in model.decoder.layers] == [True] + [False] * 7
    attn = model.encoder.layers[0].attn
    assert (attn.n_heads, attn.head_dim) == (8, 32)


# --- MADP's pieces against independent expectations ------------------------------------------

def grid_swarm(gen, b: int, n: int, hi: float, lo: float = 0.0):
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
    obs, pos = grid_swarm(gen, b, n, 300)
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
    obs, pos = grid_swarm(gen, b, n, 400)
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
    obs, pos = grid_swarm(gen, 2, 4, 300)
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
    obs, pos = grid_swarm(gen, 1, 8, 500, lo=100)
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
    obs, pos = grid_swarm(gen, 2, 6, 500)
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


def _golden_outputs() -> dict[str, torch.Tensor]:
    torch.set_num_threads(1)
    out = {}
    gen = torch.Generator().manual_seed(2026)
    b, n = 2, 7
    obs, pos = grid_swarm(gen, b, n, 420)  # r_c = 256: neighbourhoods, not one clique
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


def test_forward_is_loss_with_every_argument(gen):
    """Guards ``MADP.forward`` (what DDP calls): it passes ``k`` and ``noise`` through to ``loss``
    (mutants dropping either: a dropped ``k`` shifts ``noise`` into its place, a dropped ``noise``
    draws fresh noise)."""
    torch.manual_seed(0)
    model = MADP(tiny_madp_config()).eval()
    obs, pos = grid_swarm(gen, 2, 4, 300)
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
    obs, pos = grid_swarm(gen, b, n, 300)
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

if __name__ == "__main__":
    if "--regenerate" not in sys.argv:
        sys.exit("usage: python -m tests.models.test_madp --regenerate")
    GOLDEN.parent.mkdir(exist_ok=True)
    save_file(_golden_outputs(), str(GOLDEN))
    print(f"wrote {GOLDEN}")
