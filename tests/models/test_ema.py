import torch
from torch import nn

from madp.models import EMA


def make():
    torch.manual_seed(0)
    return nn.Sequential(nn.Linear(3, 4), nn.BatchNorm1d(4))


def test_ema_tracks_parameters_with_warmup():
    model = make()
    ema = EMA(model, decay=0.9)
    w0 = model[0].weight.detach().clone()
    with torch.no_grad():
        model[0].weight.add_(1.0)
    ema.update(model)  # first decay = min(0.9, 1/10) = 0.1
    assert torch.allclose(ema.shadow["0.weight"], 0.1 * w0 + 0.9 * (w0 + 1.0))
    for _ in range(200):
        ema.update(model)
    assert ema.current_decay() == 0.9
    assert torch.allclose(ema.shadow["0.weight"], w0 + 1.0, atol=1e-5)


def test_average_parameters_context_and_state_dict():
    model = make()
    ema = EMA(model, decay=0.5, warmup=False)
    live = model[0].weight.detach().clone()
    with torch.no_grad():
        model[0].weight.mul_(3.0)
    ema.update(model)
    expected = 0.5 * live + 0.5 * 3.0 * live
    with ema.average_parameters(model):
        assert torch.allclose(model[0].weight, expected)
    assert torch.allclose(model[0].weight, 3.0 * live)

    other = EMA(make(), decay=0.1)
    other.load_state_dict(ema.state_dict())
    assert other.decay == 0.5 and other.num_updates == 1
    assert torch.allclose(other.shadow["0.weight"], expected)
    sd = ema.shadow_state_dict()
    assert set(sd) == set(model.state_dict())
