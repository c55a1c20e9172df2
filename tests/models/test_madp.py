import pytest
import torch
from safetensors.torch import load_file, save_file

from madp.models import MADP
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


@pytest.mark.parametrize("sampler", ["ddim", "dpm++"])
def test_decentralized_equals_each_robot_running_the_model_on_its_own_neighbourhood(tiny_madp, gen, sampler):
    """The reference of the paper's decentralized execution, one robot at a time: robot i takes the
    tokens its neighbours computed for themselves, runs encoder and sampler on just its
    neighbourhood (mask recomputed among those robots, with the component term) and keeps its own
    action. Overlapping, unequal neighbourhoods, two swarms, padding. Fails if packed
    neighbourhoods see each other, if an ego reads another slot, or if noise is not shared; and
    (issue 17) on full attention inside each neighbourhood: several neighbourhoods here hold two
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
