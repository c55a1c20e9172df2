"""A swarm of robot runtimes behind the controller interface: ``madp eval --runtime onnx`` and
``madp rollout --runtime onnx``.

:class:`OnnxMADPPolicy` runs every robot of an environment through its own control step of
:class:`madp.robot.RobotRuntime` (the exported graphs, the numpy sampler): at each
control step every robot broadcasts its token (:meth:`RobotRuntime.message`), every robot's inbox
holds the messages of the robots within r_c (over a network, what its ``token`` channel delivered:
:func:`token_inboxes`), and every robot acts on its inbox. Under a ``_joint`` rule every robot then
gets the cost messages of the robots whose positions it holds (the simulator's cost round). The starting noise (``noise``) is

* ``torch`` (``madp eval --runtime onnx``): the PyTorch policy's (:class:`madp.policies.MADPPolicy`:
  one ``[K, N, 2]`` draw per environment and step from the episode's generator), so a suite run both
  ways differs only by what the runtime computes;
* ``robot`` (``madp rollout --runtime onnx``): each robot's own, :func:`madp.robot.robot_noise` of the
  swarm's shared seed (:func:`madp.swarm.world.shared_seed`: frames too), the step and the robot's id,
  what a robot process draws
  (:class:`madp.robot.RobotAgent`), so a swarm of robot processes can be checked against this one
  process.
"""

from __future__ import annotations

import atexit
import hashlib
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from madp.io.checksum import sha256_file
from madp.errors import SettingError
from madp.policies.madp import SamplingSettings, noise_generator
from madp.robot.choice import local_views
from madp.robot import RobotRuntime
from madp.sampling import NOISES  # where the starting noise comes from (module docstring)
from madp.sim.network import Message
from madp.swarm.world import shared_seed

from .onnx import export_policy

__all__ = ["OnnxMADPPolicy", "exported", "token_inboxes"]

_exports: dict[tuple, Path] = {}


def exported(policy: str | Path, sampling: SamplingSettings) -> Path:
    """A directory holding ``madp export`` of ``policy`` for ``sampling``, made once per process (a
    temporary directory named by the checkpoint's sha256 and the settings, removed when the process
    exits)."""
    digest = sha256_file(policy)
    key = (digest, tuple(sorted(sampling.as_dict().items())))
    if key not in _exports:
        name = hashlib.sha256(repr(key).encode()).hexdigest()[:16]
        out = Path(tempfile.mkdtemp(prefix=f"madp-export-{name}-"))
        atexit.register(shutil.rmtree, out, True)
        export_policy(policy, out / "export", sampling)
        _exports[key] = out / "export"
    return _exports[key]


class OnnxMADPPolicy:
    """MADP (decentralized) run robot by robot from the export of ``policy`` with ``sampling``
    (which must be one the runtime runs: :func:`madp.export.onnx.export_policy`); ``seed`` as
    :class:`madp.policies.MADPPolicy`'s; ``noise``: one of :data:`NOISES` (module docstring)."""

    def __init__(self, policy: str | Path, sampling: SamplingSettings | None = None, seed: int = 0,
                 noise: str = "torch"):
        self.sampling = sampling or SamplingSettings()
        if self.sampling.candidates < 1:
            raise SettingError("candidates", f"expected >= 1, got {self.sampling.candidates}")
        if noise not in NOISES:
            raise SettingError("noise", f"expected one of {', '.join(NOISES)}, got {noise!r}")
        self.noise = noise
        self.runtime = RobotRuntime(exported(policy, self.sampling))
        self.sampling = replace(self.sampling, select=self.runtime.rule)  # the export's (a rule's fallback: fitted)
        self.candidates = self.sampling.candidates
        self.sent: list = []
        self.reset(seed)

    def reset(self, seed: int) -> None:
        self.seed = int(seed)
        self._shared: tuple = (None, 0)  # (scenario, its shared seed)
        self.generator = noise_generator(seed)

    def act(self, env, noise: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Every robot's control step on ``env`` with starting noise ``noise [K, N, 2]`` (robot j's
        candidates in column j; None: each robot's :func:`madp.robot.robot_noise`):
        ``(actions [N, 2], candidates [K, N, 2])`` m/s."""
        rt = self.runtime
        seed = self.seed if env.scenario.seed is None else env.scenario.seed
        if noise is None:  # robot noise: the seed a swarm's robots share (madp swarm's START)
            seed = self._shared_seed(env.scenario)
        obs, pos = env.observations(), env.estimates_m()
        known, held = env.neighbour_view()  # what each robot holds of the others' positions
        views = rt.view(env.maps, local_views(env)) if rt.reads_map else None
        sent = [rt.message(i, env.steps, obs[i], pos[i], held[i][known[i]], seed) for i in range(env.num_robots)]
        self.sent = sent  # what the robots broadcast (recordings)
        if env.network is not None:
            rt.max_age = env.network.settings.max_age
        inboxes = token_inboxes(env, sent)
        draw = None if noise is None else (lambda ids: noise[:, ids])
        results = [rt.step(i, env.steps, obs[i], pos[i], inboxes[i], seed, view=None if views is None else views.row(i),
                           noise=draw, own=sent[i]) for i in range(env.num_robots)]
        actions = [r.action_mps for r in results]
        if rt.joint and results and results[0].costs is not None:  # the cost round: wherever positions are held
            costs = [rt.cost_message(r) for r in results]
            actions = [rt.choose_joint(r, [costs[j] for j in np.flatnonzero(known[i])], np.flatnonzero(known[i]))
                       for i, r in enumerate(results)]
        return np.stack(actions), np.stack([r.candidates_mps for r in results], 1)

    def _shared_seed(self, scenario) -> int:
        if self._shared[0] is not scenario:
            self._shared = (scenario, shared_seed(scenario, self.seed))
        return self._shared[1]

    def _noise(self, g: torch.Generator, n: int) -> np.ndarray | None:
        if self.noise == "robot":
            return None
        return torch.randn((self.candidates, n, self.runtime.action_dim), generator=g).numpy()

    def __call__(self, env) -> np.ndarray:
        return self.act(env, self._noise(self.generator, env.num_robots))[0]

    def act_batch(self, envs: list, generators: list[torch.Generator]) -> np.ndarray:
        """Actions ``[B, N, 2]``: environment b with noise from ``generators[b]``, drawn as the PyTorch
        policy draws it (with ``robot`` noise: each robot's own; the generators are not used)."""
        return np.stack([self.act(e, self._noise(g, e.num_robots))[0] for e, g in zip(envs, generators)])

    def sample(self, env, num_samples: int = 1, generator: torch.Generator | None = None) -> np.ndarray:
        """``num_samples`` swarm actions ``[M, N, 2]`` for the current state (recordings; with ``robot``
        noise every sample of a step is the same one)."""
        g = generator or self.generator
        return np.stack([self.act(env, self._noise(g, env.num_robots))[0] for _ in range(num_samples)])


def token_inboxes(env, sent: list[Message]) -> list[list[Message]]:
    """Each robot's inbox of token messages at this step, given every robot's ``sent [N]``: its
    neighbours' (true state) without a network, else what the ``token`` channel of the environment's
    network (:mod:`madp.sim.network`) delivered, ``Message(sender, step sent, position, token)``
    (kept ones included, up to the network's age limit)."""
    if env.network is None:
        nbr = env.neighbours()
        return [[sent[j] for j in np.flatnonzero(nbr[i])] for i in range(env.num_robots)]
    payload = np.stack([np.concatenate([m.position_m, m.token]) for m in sent])
    return env.network.exchange("token", env.steps, payload).messages()
