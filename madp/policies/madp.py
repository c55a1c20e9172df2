"""MADP behind the simulator's controller interface, ``policy(env) -> actions [N, 2]`` m/s, with a
sampler (DDIM or DPM-Solver++, S steps, η for DDIM; :class:`SamplingSettings`).

``mode="decentralized"``: each robot samples from the tokens of its own neighbourhood and keeps its
own action (what the robots would run); ``mode="centralized"``: one masked pass over the whole swarm
(a faster approximation).

On environments with a network (:mod:`madp.sim.network`) decentralized MADP runs as the robots would:
each robot computes its token from its own observation (its neighbours' channels from its inbox) and
its neighbourhood offset from the positions it holds, sends it with its position on the ``token``
channel, and samples from the tokens and positions in its own inbox (:meth:`MADP.sample_views`); a
token that arrives late was computed in the frame of the step it was sent, and is used only when that
frame is this step's (with ``frame="d4"``, 1 step in 8 on average).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING, Collection

import numpy as np
import torch

from madp.errors import SettingError
from madp.models.samplers import DEFAULT_SAMPLER, DEFAULT_SAMPLING_STEPS, check_sampler
from madp.models.symmetry import inverse_actions, transform_points, transform_state
from madp.models.attention_mask import closer_than_squared
from madp.robot.frame import frame_element  # torch-free: the robot runtime computes it too
from madp.selection import DEFAULT_RULE, RULES, check_rule, default_candidates, runnable
from madp.sim.rules import clip_speed

from .select import select_actions
from .swarm import swarm_tensors

if TYPE_CHECKING:
    from madp.sim import CoverageEnv


def noise_generator(seed: int) -> torch.Generator:
    """The sampling-noise generator of one episode, seeded by its scenario seed. It lives on the CPU
    whatever device the policy runs on: the noise is drawn there and moved to the device, so a seed
    gives the same noise on every device (results differ only by the device's float rounding)."""
    g = torch.Generator()
    g.manual_seed(int(seed) & ((1 << 63) - 1))
    return g


def check_sampling_steps(model, sampling_steps: int) -> None:
    """A one-line :class:`SettingError` unless ``model`` samples in S = ``sampling_steps``: at most its
    diffusion steps K, and exactly 1 for a model distilled into one step (it predicts the sample,
    ``madp train --distill``, and was trained at step K alone)."""
    if sampling_steps > model.schedule.num_train_steps:
        raise SettingError("sampling_steps", f"expected at most {model.schedule.num_train_steps} (the model's "
                           f"diffusion steps K), got {sampling_steps}")
    if model.config.prediction == "sample" and sampling_steps != 1:
        raise SettingError("sampling_steps", f"this policy was distilled into one sampler step: expected 1 "
                           f"(--sampling-steps 1), got {sampling_steps}")


#: The frames MADP's model may see the world in (:class:`SamplingSettings`).
FRAMES = ("world", "d4")
#: The precisions MADP may sample in (:class:`SamplingSettings`).
PRECISIONS = ("fp32", "bf16")


@dataclass(frozen=True)
class SamplingSettings:
    """How MADP samples its actions: the reverse diffusion (``sampler``, ``sampling_steps`` S, DDIM's
    ``eta``; see :mod:`madp.models.samplers`) and whether each robot's initial noise is drawn once
    per episode (``fixed_noise``), and the frame the model sees the world in (``frame``):

    * ``world``: the world's own axes;
    * ``d4``: at every control step the swarm acts in one of the world's 8 rotations and reflections
      (:mod:`madp.models.symmetry`), drawn from the episode's seed (the scenario's, else the policy's)
      and the step count (what robots sharing a seed can all compute): the state is moved by it, the model samples there, and the
      actions are moved back. The policy's action distribution is then exactly equivariant to the
      world's symmetries, and a direction the model prefers in its own axes changes every step.

    ``candidates`` K and ``select``: every robot draws K candidate actions in the same batched call
    and keeps one by rule ``select`` (:data:`madp.selection.RULES`; the default K = 4,
    ``none``: K = 1, one sample per robot).

    ``precision``: ``fp32``, or ``bf16``: the transformer's linear layers (nearly all of the sampling's
    arithmetic) hold their weights in bfloat16 and compute in it, the rest in float32
    (:meth:`madp.models.MADP.with_bf16_linears`); faster where the CPU has bfloat16 instructions, and
    the actions differ from fp32's by the rounding that compounds over the S steps.

    Checked on construction; the defaults are the measured best."""

    sampler: str = DEFAULT_SAMPLER
    sampling_steps: int = DEFAULT_SAMPLING_STEPS
    eta: float = 0.0
    fixed_noise: bool = False
    frame: str = "d4"
    select: str = DEFAULT_RULE
    candidates: int = default_candidates(DEFAULT_RULE)
    precision: str = "fp32"

    def __post_init__(self) -> None:
        check_sampler(self.sampler, self.sampling_steps, self.eta)
        if self.frame not in FRAMES:
            raise SettingError("frame", f"expected one of {', '.join(FRAMES)}, got {self.frame!r}")
        check_rule(self.select, self.candidates)
        if self.precision not in PRECISIONS:
            raise SettingError("precision", f"expected one of {', '.join(PRECISIONS)}, got {self.precision!r}")

    @classmethod
    def of(cls, sampler: str | None = None, sampling_steps: int | None = None, eta: float = 0.0,
           fixed_noise: bool = False, frame: str = "d4", select: str | None = None, candidates: int | None = None,
           precision: str = "fp32") -> "SamplingSettings":
        """The settings with ``None`` standing for the default sampler, S and selection rule, and for
        the rule's default K (:func:`madp.selection.default_candidates`)."""
        select = DEFAULT_RULE if select is None else select
        return cls(sampler or DEFAULT_SAMPLER, sampling_steps or DEFAULT_SAMPLING_STEPS, eta, fixed_noise, frame,
                   select, default_candidates(select) if candidates is None else candidates, precision)

    def fitted(self, carried: Collection[str]) -> "SamplingSettings":
        """These settings on a policy file that carries the learned networks ``carried`` (keys of
        :data:`madp.selection.NEEDS`): the rule's fallback in its place when the file lacks the network
        it needs (:func:`madp.selection.runnable`; the default ``critic`` runs ``explore`` on a file
        without a critic), else unchanged."""
        select = runnable(self.select, carried)
        return self if select == self.select else replace(self, select=select)

    def as_dict(self) -> dict:
        """What names the sampling in tables, recordings and a suite's config."""
        return asdict(self)


class MADPPolicy:
    """``seed`` fixes the sampling noise (a generator reset per episode by :meth:`reset`);
    ``sampling`` chooses the reverse diffusion (:class:`SamplingSettings`).

    ``sampling.fixed_noise``: each robot draws its initial noise ``U_K`` once per episode and reuses it
    at every control step (with a deterministic sampler the policy is then a function of the state),
    instead of a fresh draw per step; per-step noise of DDIM with η > 0 stays fresh.

    ``sampling.candidates`` K > 1: each sampling call runs K copies of every state in one batch, copy
    k with the k-th ``[N, 2]`` block of one ``[K, N, 2]`` noise draw, and ``sampling.select`` keeps
    one action per robot (:func:`select_actions`)."""

    def __init__(self, model, mode: str = "decentralized", sampling: SamplingSettings | None = None, seed: int = 0,
                 device: str = "cpu", network=None):
        if mode not in ("decentralized", "centralized"):
            raise SettingError("mode", f"expected decentralized or centralized, got {mode!r}")
        sampling = sampling or SamplingSettings()
        self.sampling = sampling = sampling.fitted(() if network is None else (RULES[sampling.select].needs,))
        check_sampling_steps(model, sampling.sampling_steps)
        model = model.with_bf16_linears() if sampling.precision == "bf16" else model
        self.model, self.mode, self.num_steps, self.eta = model.eval(), mode, int(sampling.sampling_steps), float(sampling.eta)
        self.sampler, self.fixed_noise, self.frame = sampling.sampler, bool(sampling.fixed_noise), sampling.frame
        self.select, self.candidates = sampling.select, int(sampling.candidates)
        self.network = network  # the learned network its rule reads (a map prior or a critic), if any
        self._fixed: dict[int, torch.Tensor] = {}
        self.stochastic = self.sampler == "ddim" and self.eta > 0  # fresh noise at every sampler step
        self.device = torch.device(device)
        self.reset(seed)

    def reset(self, seed: int) -> None:
        self.seed = int(seed)
        self.generator = noise_generator(seed)
        self._fixed = {}

    def _noise(self, g: torch.Generator, shape: tuple[int, ...], fixed: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The noise of one sampling call from the CPU generator ``g``, on the policy's device:
        ``U_K`` of ``shape`` (with ``fixed``: the episode's first draw, kept per generator: one
        generator per environment and episode), then, when the sampler is stochastic (DDIM with
        η > 0), one fresh draw per sampler step ``[S, *shape]``; in the order the model would draw them."""
        if not fixed:
            first = torch.randn(shape, generator=g)
        else:
            if id(g) not in self._fixed:
                self._fixed[id(g)] = torch.randn(shape, generator=g)
            first = self._fixed[id(g)]
        steps = torch.stack([torch.randn(shape, generator=g) for _ in range(self.num_steps)]) if self.stochastic else None
        return first.to(self.device), None if steps is None else steps.to(self.device)

    def _sample(self, obs: torch.Tensor, pos: torch.Tensor, noise: torch.Tensor, step_noise: torch.Tensor | None,
                envs: list["CoverageEnv"], copies: int) -> torch.Tensor:
        """Actions ``[B * C, N, 2]`` (m/s, float64 on the CPU; sample c of state b in row b·C + c) for
        ``obs [B, N, 4, S, S]``, ``pos [B, N, 2]``, the states of ``envs`` (one per b), C = ``copies``
        samples of each: the model encodes every state once and denoises its C copies."""
        fn = self.model.sample_decentralized if self.mode == "decentralized" else self.model.sample
        gs = [frame_element(self.seed if e.scenario.seed is None else e.scenario.seed, e.steps) for e in envs]
        if envs[0].network is not None:
            if self.mode != "decentralized":
                raise SettingError("mode", "a network between the robots needs decentralized MADP, got centralized")
            u = self._sample_inboxes(obs, pos, noise, step_noise, envs, copies, gs)
        else:
            if self.frame == "d4":
                moved = [transform_state(o, x, g, float(envs[0].params.world_size)) for o, x, g in zip(obs, pos, gs)]
                obs, pos = torch.stack([m[0] for m in moved]), torch.stack([m[1] for m in moved])
            u = fn(obs, pos, self.num_steps, self.eta, sampler=self.sampler, noise=noise, step_noise=step_noise,
                   copies=copies)
        u = self.model.denormalize_actions(u).double().cpu()
        if self.frame == "world":
            return u
        return torch.stack([inverse_actions(ub, g) for ub, g in zip(u, np.repeat(gs, copies))])

    def _sample_inboxes(self, obs: torch.Tensor, own: torch.Tensor, noise: torch.Tensor, step_noise: torch.Tensor | None,
                        envs: list["CoverageEnv"], copies: int, gs: list[int]) -> torch.Tensor:
        """Decentralized sampling through every robot's inbox (module docstring): ``obs [B, N, 4, S, S]``
        and ``own [B, N, 2]`` (each robot's own observation and position estimate, world frame) ->
        normalised actions ``[B * C, N, 2]`` in each environment's frame."""
        model, dev, r_c = self.model, self.device, self.model.config.comm_radius_m
        b, n = own.shape[:2]
        world = float(envs[0].params.world_size)
        gs = gs if self.frame == "d4" else [0] * b
        eye = torch.eye(n, dtype=torch.bool, device=dev)

        def frame(points: np.ndarray | torch.Tensor, k: int) -> torch.Tensor:  # world -> env k's frame, float32
            t = torch.as_tensor(np.asarray(points, dtype=np.float32) if isinstance(points, np.ndarray) else points)
            return transform_points(t.to(dev), gs[k], world)

        moved = [transform_state(o, x, g, world) for o, x, g in zip(obs, own, gs)]
        obs, own_f = torch.stack([m[0] for m in moved]), torch.stack([m[1] for m in moved])
        views = [e.neighbour_view() for e in envs]  # each robot's (known [N, N], held positions [N, N, 2])
        held = torch.stack([frame(v[1], k) for k, v in enumerate(views)])  # [B, N, N, 2]
        held = torch.where(eye[..., None], own_f[:, :, None], held)
        known = torch.from_numpy(np.stack([v[0] for v in views])).to(dev)
        near = closer_than_squared(held - own_f[:, :, None], r_c)
        mask = (known & near) | eye
        tokens = model.embed_tokens(obs, own_f, mask, None, offsets_m=held - own_f[:, :, None])  # [B, N, T]
        width = tokens.shape[-1]
        tokens_v = torch.empty(b, n, n, width, dtype=tokens.dtype, device=dev)
        pos_v = torch.empty(b, n, n, 2, dtype=own_f.dtype, device=dev)
        member = torch.empty(b, n, n, dtype=torch.bool, device=dev)
        key = torch.empty(b, n, n, dtype=torch.long, device=dev)
        for k, e in enumerate(envs):  # each robot sends its position and token; what each robot holds
            sent = np.concatenate([e.estimates_m(), tokens[k].double().cpu().numpy()], axis=1)
            rec = e.network.exchange("token", e.steps, sent)
            pos_v[k] = frame(rec.payload[:, :, :2], k)
            tokens_v[k] = torch.from_numpy(rec.payload[:, :, 2:].astype(np.float32)).to(dev, tokens.dtype)
            member[k] = torch.from_numpy(rec.valid & self._same_frame(e, rec.sent_step, gs[k])).to(dev)
            key[k] = torch.from_numpy(rec.sent_step + 1).to(dev)
        pos_v = torch.where(eye[..., None], own_f[:, :, None], pos_v)
        tokens_v = torch.where(eye[..., None], tokens[:, :, None], tokens_v)
        member = (member & closer_than_squared(pos_v - own_f[:, :, None], r_c)) | eye
        key = torch.where(eye, torch.tensor([e.steps + 1 for e in envs], device=dev)[:, None, None], key)
        valid = torch.ones(b, n, dtype=torch.bool, device=dev)
        return model.sample_views(tokens_v, pos_v, member, valid, self.num_steps, self.eta, noise=noise,
                                  step_noise=step_noise, key=key, sampler=self.sampler, copies=copies)

    def _same_frame(self, env: CoverageEnv, sent_step: np.ndarray, g: int) -> np.ndarray:
        """``[N, N]`` bool: which held tokens, sent at ``sent_step [N, N]``, were computed in this step's
        frame ``g`` (a token means nothing in another frame; all of them with ``frame="world"``)."""
        if self.frame != "d4":
            return np.ones(sent_step.shape, bool)
        seed = self.seed if env.scenario.seed is None else env.scenario.seed
        frames = {int(s): frame_element(seed, int(s)) if s >= 0 else -1 for s in np.unique(sent_step)}
        return np.vectorize(lambda s: frames[int(s)] == g, otypes=[bool])(sent_step) | (sent_step == env.steps)

    @torch.inference_mode()  # the actions leave as numpy arrays
    def sample(self, env: CoverageEnv, num_samples: int = 1, generator: torch.Generator | None = None) -> np.ndarray:
        """``num_samples`` independent swarm actions [M, N, 2] (m/s) for the current state (each the
        one ``sampling.select`` keeps among its own K candidates).

        ``generator`` (a CPU generator; default: the policy's own) lets a caller draw extra samples,
        e.g. for visualisation, without changing the noise the rollout itself uses."""
        own = generator is None
        generator = generator or self.generator
        copies = num_samples * self.candidates
        obs, pos = swarm_tensors([env], self.device)
        shape = (copies, env.num_robots, self.model.config.action_dim)
        noise, steps = self._noise(generator, shape, own and self.fixed_noise and num_samples == 1)
        u = self._sample(obs, pos, noise, steps, [env], copies).numpy()
        return self._choose(np.stack([clip_speed(x, env.params.max_speed_mps) for x in u]), [env] * num_samples)

    def _choose(self, u: np.ndarray, envs: list[CoverageEnv]) -> np.ndarray:
        """``u [B·K, N, 2]`` (copy k of state b in row b·K + k) -> the kept actions ``[B, N, 2]``."""
        k = self.candidates
        if k == 1:
            return u
        u = u.reshape(len(envs), k, *u.shape[1:])
        return np.stack([select_actions(self.select, e, c, self.network) for e, c in zip(envs, u)])

    def __call__(self, env: CoverageEnv) -> np.ndarray:
        return self.sample(env, 1)[0]

    @torch.inference_mode()  # the actions leave as numpy arrays
    def act_batch(self, envs: list[CoverageEnv], generators: list[torch.Generator]) -> np.ndarray:
        """Actions ``[B, N, 2]`` (m/s) for B environments with the same N, sampled as one batch.

        Environment b's noise comes from ``generators[b]`` (CPU generators) in the order a lone
        :meth:`sample` would draw it (U_K, then one draw per step when the sampler is stochastic:
        DDIM with η > 0), so batching changes only float rounding. With K candidates the K copies of
        environment b are rows b·K .. b·K + K − 1 of the batch."""
        obs, pos = swarm_tensors(envs, self.device)
        k = self.candidates
        copies = [e for e in envs for _ in range(k)]
        shape = (k, pos.shape[1], self.model.config.action_dim)
        noise = [self._noise(g, shape, self.fixed_noise) for g in generators]
        first = torch.cat([n[0] for n in noise])
        steps = torch.cat([n[1] for n in noise], dim=1) if self.stochastic else None
        u = self._sample(obs, pos, first, steps, envs, k).numpy()
        return self._choose(np.stack([clip_speed(x, e.params.max_speed_mps) for x, e in zip(u, copies)]), envs)
