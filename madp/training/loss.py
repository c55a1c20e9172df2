"""What one training step computes: the generator and the diffusion draws of a step, and the loss of
one micro-batch (the DDPM loss, LPAC-K3's regression, or a distillation's one-step loss)."""

from __future__ import annotations

from contextlib import nullcontext

import numpy as np
import torch

from .comm_dropout import draw_links, drop_neighbour_channels
from .config import TrainConfig


#: Streams of :func:`step_generator`: a training step's diffusion draws, a validation batch's, and their
#: communication dropout's (links drawn apart, so the diffusion draws do not depend on it).
TRAIN_STREAM, VAL_STREAM, TRAIN_LINKS_STREAM, VAL_LINKS_STREAM = 0, 1, 2, 3


def step_generator(seed: int, step: int, device: torch.device, stream: int = 0) -> torch.Generator:
    """The generator of training step ``step`` (stream 0) or validation batch ``step`` (stream 1);
    streams 2 and 3: their communication dropout's."""
    g = torch.Generator(device=device)
    g.manual_seed(int(np.random.SeedSequence([seed, stream, step]).generate_state(1, np.uint64)[0] >> 1))
    return g


def step_noise(raw, generator: torch.Generator, batch: dict, parts: int, num_robots: int | None = None) -> tuple:
    """The diffusion steps ``k [P, B]`` and noise ``[P, B, N, 2]`` of one optimizer step's global batch.

    The global batch is ``parts`` = ranks x micro-batches pieces of ``B`` samples; one draw covers it
    (``k`` for all, then the noise for all) and each piece takes its slice, so a sample's noise
    depends on its place in the global batch, not on how many processes share it: ``torchrun
    --nproc_per_node R`` equals one process with ``--grad-accum R`` and R times the loader workers.
    With one part this is exactly what ``MADP.loss`` would draw itself. ``num_robots``: the largest N
    of the datasets (default the batch's), so that a part of smaller swarms takes ``noise[..., :n, :]``."""
    b, n = batch["actions"].shape[:2]
    n = max(n, num_robots or 0)
    device = batch_device(raw)
    k = raw.schedule.sample_timesteps(b * parts, device, generator)
    noise = torch.randn((b * parts, n, raw.config.action_dim), generator=generator, device=device, dtype=raw.dtype)
    return k.view(parts, b), noise.view(parts, b, n, -1)


def step_links(cfg: TrainConfig, step: int, device: torch.device, batch: dict, parts: int,
               num_robots: int | None = None, stream: int = TRAIN_LINKS_STREAM) -> torch.Tensor | None:
    """The links ``[P, B, N, N]`` bool of one optimizer step's (or validation batch's) global batch
    (:func:`madp.training.comm_dropout.draw_links` with ``cfg.comm_dropout``), None when it is 0.

    As :func:`step_noise`: one draw for the ``parts`` pieces of ``B`` samples, N the largest of the
    datasets (a part of smaller swarms takes ``[..., :n, :n]``), from its own generator (``stream``)."""
    if not cfg.comm_dropout:
        return None
    b, n = batch["actions"].shape[:2]
    n = max(n, num_robots or 0)
    g = step_generator(cfg.seed, step, device, stream)
    return draw_links(g, b * parts, n, cfg.comm_dropout).view(parts, b, n, n)


def batch_device(model: torch.nn.Module) -> torch.device:
    return next(model.parameters()).device


def batch_loss(model, raw, batch: dict, cfg: TrainConfig, draws: tuple | None, device, teacher=None,
               links: torch.Tensor | None = None) -> torch.Tensor:
    """The loss of one micro-batch; ``draws`` = :func:`step_noise` (MADP) or None (LPAC-K3). With a
    ``teacher`` (distillation) the target is its sample from the draw's noise, in float32. ``links``
    ``[B, N', N']`` (a piece of :func:`step_links`, N' >= N; MADP's DDPM loss only): the robots that
    still hear each other; the observations' neighbour channels and the attention follow them."""
    obs = batch["obs"].to(device, non_blocking=True)
    pos = batch["pos_m"].to(device, non_blocking=True)
    act = raw.normalize_actions(batch["actions"].to(device, non_blocking=True))
    valid = batch["valid"].to(device) if "valid" in batch else None  # padding of mixed swarm sizes
    extra = {}
    if links is not None:
        n = obs.shape[1]
        links = links[:, :n, :n].to(device)
        obs = drop_neighbour_channels(obs, pos, links, raw.config.comm_radius_m, valid)
        extra = {"links": links}
    if teacher is not None:
        noise = draws[1][:, :obs.shape[1]]
        target = teacher.sample(obs, pos, cfg.distill_steps, valid=valid, noise=noise)  # no_grad, float32
    autocast = torch.autocast("cuda", dtype=torch.bfloat16) if device.type == "cuda" else nullcontext()
    with autocast:
        if teacher is not None:
            return model(obs, pos, target, valid, None, None, noise, one_step=True)
        if cfg.model == "madp":
            k, noise = draws
            # forward = DDPM loss (through DDP if wrapped); noise drawn for the largest N, sliced to this batch's
            return model(obs, pos, act, valid, None, k, noise[:, :obs.shape[1]], **extra)
        if valid is None:
            return torch.nn.functional.mse_loss(model(obs, pos).float(), act)
        w = valid.unsqueeze(-1).float()
        return ((model(obs, pos, valid).float() - act).square() * w).sum() / (w.sum() * act.shape[-1])
