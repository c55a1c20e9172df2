import json

import pytest

from madp.models import LPACConfig, MADPConfig, lpac_config, madp_config


def test_paper_preset_matches_spec():
    c = madp_config("paper")
    assert (c.d_model, c.n_heads, c.head_dim) == (256, 8, 32)
    assert (c.n_enc_layers, c.n_dec_layers) == (8, 8)
    assert c.z_dim == 32 and c.token_dim == 34
    assert len(c.cnn_channels) == 3
    assert (c.comm_radius_m, c.world_size, c.rope_tau, c.rope_layers) == (256.0, 1024.0, 1024.0, 1)
    assert (c.num_train_steps, c.beta_start, c.beta_end) == (1000, 1e-4, 0.02)
    lp = lpac_config("paper")
    assert (lp.cnn_channels, lp.cnn_stride, lp.cnn_padding) == ((32, 32, 32), 1, 0)
    assert (lp.gnn_layers, lp.gnn_hops, lp.gnn_hidden) == (5, 3, 256)
    assert lp.mlp_hidden == (32, 32)


def test_cpu_preset_is_smaller():
    p, c = madp_config("paper"), madp_config("cpu")
    assert c.d_model < p.d_model and c.n_enc_layers < p.n_enc_layers
    assert c.head_dim % 4 == 0


@pytest.mark.parametrize("cls,make", [(MADPConfig, madp_config), (LPACConfig, lpac_config)])
@pytest.mark.parametrize("preset", ["paper", "cpu"])
def test_dict_round_trip_through_json(cls, make, preset):
    c = make(preset)
    back = cls.from_dict(json.loads(json.dumps(c.to_dict())))
    assert back == c


def test_overrides_and_validation():
    assert madp_config("cpu", n_enc_layers=3).n_enc_layers == 3
    with pytest.raises(ValueError):
        madp_config("gpu")
    with pytest.raises(ValueError):
        MADPConfig(d_model=40, n_heads=4)  # head dim 10 not divisible by 4
    with pytest.raises(ValueError):
        MADPConfig.from_dict({"nope": 1})


@pytest.mark.parametrize("cls", [MADPConfig, LPACConfig])
def test_configs_of_earlier_checkpoints_still_load(cls):
    """Checkpoints written before the radius carried its unit in its name (``comm_radius``, as the
    shipped ones) load with the value in ``comm_radius_m``."""
    assert cls.from_dict({"comm_radius": 128.0}) == cls(comm_radius_m=128.0)
    assert "comm_radius" not in cls().to_dict()
