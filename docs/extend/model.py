"""A model of your own: a torch module from each robot's observation [4, 32, 32] to its velocity,
trained on the clairvoyant expert's actions, then run as a controller."""

import numpy as np
import torch
from torch import nn

from madp.sim import ClairvoyantCVT, CoverageEnv, Scenario, rollout

torch.manual_seed(0)


class TinyPolicy(nn.Module):
    """Per-robot CNN: observation [N, 4, 32, 32] -> velocity [N, 2] in m/s (at most 5 m/s)."""

    def __init__(self, max_speed_mps: float = 5.0) -> None:
        super().__init__()
        self.max_speed_mps = max_speed_mps
        self.net = nn.Sequential(nn.Conv2d(4, 8, 4, stride=4), nn.ReLU(), nn.Flatten(),
                                 nn.Linear(8 * 8 * 8, 2), nn.Tanh())

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return self.max_speed_mps * self.net(observations)



class TinyController:
    """The controller interface around the model: ``controller(env) -> actions [N, 2]`` m/s."""

    def __init__(self, model: TinyPolicy) -> None:
        self.model = model.eval()

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        with torch.no_grad():
            return self.model(torch.from_numpy(env.observations())).numpy().astype(np.float64)


# expert samples: (observations, the expert's actions) along its own rollout
env, expert = CoverageEnv(Scenario.random(seed=1)), ClairvoyantCVT()
observations, actions = [], []
for _ in range(20):
    observations.append(env.observations())
    actions.append(expert(env))
    env.step(actions[-1])
x = torch.from_numpy(np.concatenate(observations)).float()
y = torch.from_numpy(np.concatenate(actions)).float()

model = TinyPolicy()
optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
losses = []
for step in range(30):
    loss = nn.functional.mse_loss(model(x), y)
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    losses.append(loss.item())
print(f"loss {losses[0]:.2f} -> {losses[-1]:.2f}")
assert losses[-1] < losses[0]

result = rollout(CoverageEnv(Scenario.random(seed=2)), TinyController(model), steps=10)
print(f"TinyPolicy: J(10)/J(0) = {result.normalized_cost[-1]:.3f}")
assert np.isfinite(result.normalized_cost).all()
