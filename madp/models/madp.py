"""MADP: multi-agent diffusion policy (paper §III).

Per robot i: ``O_i [4, 32, 32] --CNN--> z_i [32]``; token ``[z_i, p_i] [34]`` (``p_i``: see below)
``--Linear--> [d_model]``; the spatial-transformer encoder Psi_E turns the tokens into a memory
(once per control step). The decoder Psi_D maps noisy normalised actions ``U_k [N, 2]`` plus an
embedding of the diffusion step k, cross-attending to the memory, to the predicted noise
``eps_hat [N, 2]``; the sampler (DDIM or DPM-Solver++, :mod:`.samplers`) runs it S times.

Position feature ``p_i`` (``config.pos_token``). The paper writes the token as ``[z_i, x_i]`` with
the absolute position, yet argues the spatial transformer is shift equivariant; an absolute
position in the token would break that. Here positions reach attention through RoPE (relative by
construction), and the token carries ``p_i = (x_i - mean_{j in M_i} x_j) / r_c``, robot i's offset
from the centroid of its own attention neighbourhood ``M_i`` (incl. itself): shift invariant,
permutation equivariant, local (robot i knows its neighbours' positions) and bounded in (-1, 1).
``pos_token="none"`` puts zeros there (positions only through RoPE).

Shapes: ``obs [B, N, 4, 32, 32]``, ``pos_m [B, N, 2]`` (metres), ``valid [B, N]`` bool (False =
padding robot; None = all valid), ``actions_norm [B, N, 2]`` (normalised by the dataset's action
statistics, see :meth:`MADP.normalize_actions`), ``mask [B, N, N]`` bool, ``memory [B, N, d_model]``,
``k [B]`` long diffusion steps in 1..K.
"""

from __future__ import annotations

import copy
import math
from typing import Callable

import torch
from torch import Tensor, nn

from .action_stats import ActionStatsMixin
from .attention_mask import attention_mask, packed_neighbourhood_mask, pairwise_offsets
from .config import MADPConfig
from .diffusion import DDPMSchedule
from .packing import pack_neighbourhoods
from .perception import PerceptionCNN, apply_per_robot
from .samplers import DEFAULT_SAMPLER, DEFAULT_SAMPLING_STEPS, make_sampler, sample_loop
from .transformer import Rope, RotaryEmbedding2D, SpatialTransformerDecoder, SpatialTransformerEncoder, attention_bias

__all__ = ["MADP", "TimestepEmbedding"]


def _masked_mean(err: Tensor, valid: Tensor | None) -> Tensor:
    """Mean of ``err [B, N, A]`` over the valid robots (``valid [B, N]``, None: all) and A."""
    if valid is None:
        return err.mean()
    w = valid.unsqueeze(-1).to(err.dtype)
    return (err * w).sum() / (w.sum() * err.shape[-1]).clamp_min(1)


class TimestepEmbedding(nn.Module):
    """Diffusion step ``k [B]`` -> ``[B, d_model]``: sinusoidal features (transformer style, max
    period 10^4 in units of k) -> Linear -> LeakyReLU -> Linear."""

    def __init__(self, dim: int, d_model: int, leaky_slope: float = 0.01):
        super().__init__()
        if dim % 2:
            raise ValueError("time embedding dim must be even")
        self.dim = dim
        self.mlp = nn.Sequential(nn.Linear(dim, 4 * d_model), nn.LeakyReLU(leaky_slope), nn.Linear(4 * d_model, d_model))

    def sinusoidal(self, k: Tensor) -> Tensor:
        half = self.dim // 2
        freqs = torch.exp(-math.log(10000.0) * torch.arange(half, device=k.device, dtype=torch.float32) / half)
        args = k.float().unsqueeze(-1) * freqs
        return torch.cat([args.sin(), args.cos()], dim=-1)

    def forward(self, k: Tensor) -> Tensor:
        w = self.mlp[0].weight
        return self.mlp(self.sinusoidal(k).to(w.dtype))


class MADP(ActionStatsMixin):
    """Multi-agent diffusion policy (encoder once, decoder S times).

    Main entry points:

    * ``loss(obs, pos_m, actions_norm, valid=None, generator=None)`` (= ``forward``): DDPM
      epsilon-MSE over valid robots; ``one_step_loss``: the distillation loss of a model that
      predicts the sample in one step (``config.prediction = "sample"``).
    * ``sample(obs, pos_m, num_steps, eta=0.0, sampler=...)``: *centralized-masked* sampling, the whole
      swarm in one pass with the attention mask (a fast approximation of decentralized execution:
      information can travel several hops through the layers).
    * ``sample_decentralized(obs, pos_m, ...)``: *decentralized* execution: every robot runs the model
      on its own neighbourhood (itself + the robots in its attention mask) and keeps only its own
      action; all neighbourhoods run packed side by side (identical ones computed once).
    """

    #: Row length (tokens) of the packed layout of :meth:`sample_decentralized` (a neighbourhood longer than it
    #: takes rows of a multiple of it). With next-fit packing 32 was fastest (docs/reports/2026-12-01-sampler-steps.md);
    #: best-fit decreasing fills rows of any length nearly full, and 16 then beat 32 (CPU attention costs less per
    #: token in rows of 16, and lengths that are not a multiple of 16 cost several times more).
    decentralized_row_tokens: int = 16

    def __init__(self, config: MADPConfig | None = None):
        super().__init__()
        cfg = config or MADPConfig()
        self.config = cfg
        self.cnn = PerceptionCNN(cfg.obs_channels, cfg.obs_size, cfg.cnn_channels, cfg.cnn_kernel, cfg.cnn_stride,
                                 cfg.cnn_padding, cfg.cnn_norm, cfg.z_dim, cfg.leaky_slope)
        self.token_proj = nn.Linear(cfg.token_dim, cfg.d_model)
        self.rope = RotaryEmbedding2D(cfg.head_dim, cfg.rope_tau)
        self.encoder = SpatialTransformerEncoder(cfg.d_model, cfg.n_heads, cfg.n_enc_layers, cfg.mlp_ratio,
                                                 cfg.dropout, cfg.leaky_slope, cfg.rope_layers)
        self.action_in = nn.Linear(cfg.action_dim, cfg.d_model)
        self.time_embed = TimestepEmbedding(cfg.time_embed_dim or cfg.d_model, cfg.d_model, cfg.leaky_slope)
        self.decoder = SpatialTransformerDecoder(cfg.d_model, cfg.n_heads, cfg.n_dec_layers, cfg.mlp_ratio,
                                                 cfg.dropout, cfg.leaky_slope, cfg.rope_layers)
        self.head = nn.Linear(cfg.d_model, cfg.action_dim)
        self.schedule = DDPMSchedule(cfg.num_train_steps, cfg.beta_start, cfg.beta_end)
        self._init_action_stats(cfg.action_dim)
        self._init_weights()

    # ------------------------------------------------------------------------------------ set-up
    def _init_weights(self) -> None:
        """nanoGPT-style: Linear ~ N(0, 0.02), zero bias; residual-branch output projections scaled
        by 1/sqrt(2 L) with L the total number of transformer layers. Convs keep PyTorch's init."""
        n_layers = self.config.n_enc_layers + self.config.n_dec_layers
        for m in self.modules():
            if isinstance(m, nn.Linear):
                std = 0.02 / math.sqrt(2 * n_layers) if getattr(m, "is_residual_proj", False) else 0.02
                nn.init.normal_(m.weight, 0.0, std)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)

    @property
    def dtype(self) -> torch.dtype:
        return self.head.weight.dtype

    # -------------------------------------------------------------------------------- conditioning
    def attention_mask(self, pos_m: Tensor, valid: Tensor | None = None, links: Tensor | None = None) -> Tensor:
        """``[B, N, N]`` bool: distance < r_c (AND heard: ``links [B, N, N]``, None = all) AND same
        communication component; see :func:`madp.models.attention_mask.attention_mask`."""
        return attention_mask(pos_m, self.config.comm_radius_m, valid, links)

    def embed_tokens(self, obs: Tensor, pos_m: Tensor, mask: Tensor, valid: Tensor | None = None,
                     offsets_m: Tensor | None = None) -> Tensor:
        """What each robot computes for itself and shares: ``tokens [B, N, 34] = [z_i, p_i]``.

        ``z_i = CNN(O_i)``; ``p_i`` the neighbourhood offset (module docstring) over row i of ``mask``,
        from ``offsets_m [B, N, N, 2]`` (what robot i holds of x_j − x_i; default: the offsets of
        ``pos_m``). Padding rows are 0.
        """
        cfg = self.config
        z = apply_per_robot(self.cnn, obs.to(self.dtype), valid, cfg.z_dim)
        if cfg.pos_token == "neighbourhood_offset":
            w = mask.to(pos_m.dtype)  # padding columns are already False (except a padding row's diagonal)
            off = pairwise_offsets(pos_m) if offsets_m is None else offsets_m  # [B, N, N, 2], x_j - x_i
            p = -(w.unsqueeze(-1) * off).sum(-2) / w.sum(-1, keepdim=True).clamp_min(1)
            p = (p / cfg.comm_radius_m).to(z.dtype)
        else:
            p = z.new_zeros(*z.shape[:-1], 2)
        tokens = torch.cat([z, p], dim=-1)
        if valid is not None:
            tokens = tokens * valid.unsqueeze(-1).to(tokens.dtype)
        return tokens

    def encode_tokens(self, tokens: Tensor, pos_m: Tensor, mask: Tensor, rope: Rope | None = None) -> Tensor:
        """Psi_E: ``tokens [B, N, 34]`` -> ``memory [B, N, d_model]``; ``mask`` bool or its additive bias,
        ``rope`` the rotations of ``pos_m`` when the caller has them (default: computed here)."""
        rope = self.rope(pos_m, self.dtype) if rope is None else rope
        return self.encoder(self.token_proj(tokens), mask, rope)

    def encode(self, obs: Tensor, pos_m: Tensor, valid: Tensor | None = None,
               links: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """CNN + encoder, once per control step: ``-> (memory [B, N, d_model], mask [B, N, N])``; ``links``:
        see :meth:`attention_mask` (the tokens' neighbourhood offsets follow the mask)."""
        mask = self.attention_mask(pos_m, valid, links)
        tokens = self.embed_tokens(obs, pos_m, mask, valid)
        return self.encode_tokens(tokens, pos_m, mask), mask

    # ---------------------------------------------------------------------------------- denoising
    def _head_out(self, x: Tensor, k: Tensor | int, memory_kv: list, rope, mask: Tensor) -> Tensor:
        """The head's raw output for ``x`` at step ``k``: the noise or the sample (``config.prediction``)."""
        b = x.shape[0]
        if not isinstance(k, Tensor) or k.dim() == 0:
            k = torch.full((b,), int(k), device=x.device, dtype=torch.long)
        h = self.action_in(x.to(self.dtype)) + self.time_embed(k).unsqueeze(1)
        return self.head(self.decoder(h, mask, rope, memory_kv))

    def _as_eps(self, out: Tensor, x_k: Tensor, k: Tensor | int) -> Tensor:
        """The head's output as the noise estimate: itself for an ``epsilon`` model; for a ``sample``
        model ``eps = (x_k - sqrt(abar_k) U0_hat) / sqrt(1 - abar_k)`` (in float32, cast back), so every
        sampler drives both kinds alike. ``k`` an int or ``[B]``; never 0."""
        if self.config.prediction == "epsilon":
            return out
        return self.schedule.predict_eps(x_k.float(), out.float(), k).to(out.dtype)

    def _denoise(self, x: Tensor, k: Tensor | int, memory_kv: list, rope, mask: Tensor) -> Tensor:
        return self._as_eps(self._head_out(x, k, memory_kv, rope, mask), x, k)

    def denoise(self, noisy_actions: Tensor, k: Tensor | int, memory: Tensor, pos_m: Tensor, mask: Tensor,
                valid: Tensor | None = None) -> Tensor:
        """Psi_D: ``noisy_actions [B, N, 2]``, ``k [B]`` (or int) -> ``eps_hat [B, N, 2]`` (0 at padding)."""
        rope = self.rope(pos_m, self.dtype)
        eps = self._denoise(noisy_actions, k, self.decoder.memory_kv(memory, rope), rope, mask)
        if valid is not None:
            eps = eps * valid.unsqueeze(-1).to(eps.dtype)
        return eps

    # ----------------------------------------------------------------------------------- training
    def loss(self, obs: Tensor, pos_m: Tensor, actions_norm: Tensor, valid: Tensor | None = None,
             generator: torch.Generator | None = None, k: Tensor | None = None,
             noise: Tensor | None = None, links: Tensor | None = None) -> Tensor:
        """DDPM loss ``E ||eps - eps_hat(U_k, O; k)||^2``: mean over valid robots and action dims.

        ``k ~ U{1..K}`` per sample and ``noise ~ N(0, I)`` are drawn with ``generator`` (which must
        live on the tensors' device) unless given. ``links [B, N, N]`` bool: which robots hear each
        other (encoder and decoder attend only over those; None: all), see
        :mod:`madp.training.comm_dropout`.
        """
        b = actions_norm.shape[0]
        actions_norm = actions_norm.to(self.dtype)
        memory, mask = self.encode(obs, pos_m, valid, links)
        if k is None:
            k = self.schedule.sample_timesteps(b, actions_norm.device, generator)
        if noise is None:
            noise = torch.randn(actions_norm.shape, generator=generator, device=actions_norm.device,
                                dtype=actions_norm.dtype)
        x_k = self.schedule.add_noise(actions_norm, noise, k)
        eps_hat = self.denoise(x_k, k, memory, pos_m, mask)
        return _masked_mean((eps_hat - noise).square(), valid)

    def one_step_loss(self, obs: Tensor, pos_m: Tensor, target_norm: Tensor, noise: Tensor,
                      valid: Tensor | None = None) -> Tensor:
        """Distillation loss of a ``sample`` model (``config.prediction``):
        ``E ||U0_hat(U_K = noise, O; K) - target||^2``, the clean actions it predicts in one step from
        the pure noise ``noise [B, N, 2]`` at the last diffusion step K, against ``target_norm [B, N, 2]``
        (a teacher's sample from the same noise); mean over valid robots and action dims, in float32."""
        if self.config.prediction != "sample":
            raise ValueError("one_step_loss trains a model that predicts the sample (config.prediction = 'sample')")
        memory, mask = self.encode(obs, pos_m, valid)
        rope = self.rope(pos_m, self.dtype)
        out = self._head_out(noise.to(self.dtype), self.schedule.num_train_steps, self.decoder.memory_kv(memory, rope),
                             rope, mask)
        return _masked_mean((out.float() - target_norm.float()).square(), valid)

    def forward(self, obs: Tensor, pos_m: Tensor, actions_norm: Tensor, valid: Tensor | None = None,
                generator: torch.Generator | None = None, k: Tensor | None = None,
                noise: Tensor | None = None, one_step: bool = False, links: Tensor | None = None) -> Tensor:
        """Training loss (see :meth:`loss`; with ``one_step``, :meth:`one_step_loss` of ``actions_norm``
        from ``noise``, which takes no ``links``); ``forward`` so that DDP/compile wrappers see it."""
        if one_step:
            if links is not None:
                raise ValueError("links: only the DDPM loss takes links, not one_step_loss")
            return self.one_step_loss(obs, pos_m, actions_norm, noise, valid)
        return self.loss(obs, pos_m, actions_norm, valid, generator, k, noise, links)

    # ----------------------------------------------------------------------------------- sampling
    def _sampling_rope(self, pos_m: Tensor) -> Rope:
        """The RoPE rotations of ``pos_m [B, N, 2]`` as sampling applies them: the complex table
        (:meth:`RotaryEmbedding2D.rotations`, one complex multiply per rotation) where the model computes
        in float32 or float64 off MPS, else ``(cos, sin)`` in the model's dtype (bfloat16)."""
        if self.dtype in (torch.float32, torch.float64) and pos_m.device.type != "mps":
            return self.rope.rotations(pos_m, self.dtype)
        return self.rope(pos_m, self.dtype)

    def _state_dtype(self) -> torch.dtype:
        """The dtype of the sampler's state ``x`` (noise, steps, actions): the model's, at least float32."""
        return torch.promote_types(self.dtype, torch.float32)

    def _sample_loop(self, memory: Tensor, pos_m: Tensor, mask: Tensor, x: Tensor, sampler,
                     step_noise: Callable[[int], Tensor] | None) -> Tensor:
        """Reverse diffusion ``x = U_{k_S} [B, N, 2]`` -> ``U_0`` with ``sampler`` (:mod:`.samplers`):
        :meth:`_denoise_loop` with every layer's cross-attention K/V of the memory, the RoPE rotations
        and the attention mask as an additive bias, computed once for all S decoder passes."""
        rope = self._sampling_rope(pos_m)
        return self._denoise_loop(self.decoder.memory_kv(memory, rope), rope, attention_bias(mask, self.dtype), x,
                                  sampler, step_noise)

    def _copies_context(self, memory: Tensor, rope: Rope, bias: Tensor, copies: int) -> tuple[list, Rope, Tensor]:
        """What the decoder passes over C = ``copies`` copies of every row of ``memory [R, L, d]`` hold fixed:
        every layer's cross-attention K/V (computed once per row), the RoPE rotations and the additive
        attention bias ``[R, 1, L, L]``, each repeated C times (row r, copy c -> row r * C + c)."""
        memory_kv = self.decoder.memory_kv(memory, rope)
        if copies == 1:
            return memory_kv, rope, bias

        def rep(t: Tensor) -> Tensor:
            return t.repeat_interleave(copies, 0)

        rope = rep(rope) if isinstance(rope, Tensor) else (rep(rope[0]), rep(rope[1]))
        return [(rep(k), rep(v)) for k, v in memory_kv], rope, rep(bias)

    def _denoise_loop(self, memory_kv: list, rope: Rope, bias: Tensor, x: Tensor, sampler,
                      step_noise: Callable[[int], Tensor] | None) -> Tensor:
        """The S decoder passes of the reverse diffusion from ``x = U_{k_S} [B, N, 2]``, given the decoder's
        cross-attention K/V, RoPE rotations and additive attention bias; the time embedding of each of
        the S steps is computed once (one MLP call on ``[S]``)."""
        temb = self.time_embed(torch.tensor(sampler.timesteps, device=x.device, dtype=torch.long))  # [S, d]

        def denoise(x_k: Tensor, i: int, k: int) -> Tensor:
            h = self.action_in(x_k.to(self.dtype)) + temb[i]
            return self._as_eps(self.head(self.decoder(h, bias, rope, memory_kv)), x_k, k)

        return sample_loop(sampler, denoise, x, step_noise)

    def with_bf16_linears(self) -> "MADP":
        """A copy of this model for bfloat16 sampling: the linear layers of its encoder and decoder (nearly
        all of a control step's arithmetic) hold their weights in bfloat16 and compute in it, each casting
        its input (:mod:`.transformer`); the residual stream, layer norms, RoPE (float64 angles, as ever),
        attention, the CNN, the token, action and time embeddings, the head, the sampler's state and the
        action statistics stay in this model's dtype. This model is left as it is."""
        model = copy.deepcopy(self)
        for layer in (*model.encoder.modules(), *model.decoder.modules()):
            if isinstance(layer, nn.Linear):
                layer.to(torch.bfloat16)
        return model

    def make_sampler(self, sampler: str, num_steps: int, eta: float = 0.0, clip_x0: float | None = None):
        """A fresh ``"ddim"`` / ``"dpm++"`` sampler on this model's schedule (see :mod:`.samplers`)."""
        return make_sampler(sampler, self.schedule, num_steps, eta, clip_x0)

    @torch.no_grad()
    def sample(self, obs: Tensor, pos_m: Tensor, num_steps: int = DEFAULT_SAMPLING_STEPS, eta: float = 0.0,
               generator: torch.Generator | None = None, valid: Tensor | None = None,
               noise: Tensor | None = None, step_noise: Tensor | None = None,
               clip_x0: float | None = None, sampler: str = DEFAULT_SAMPLER, copies: int = 1) -> Tensor:
        """Centralized-masked sampling of the whole swarm -> ``actions_norm [B, N, 2]``
        (``[B * copies, N, 2]``: see ``copies``).

        Args:
            num_steps: S sampler steps; sampler: ``"ddim"`` (paper Algorithm 1, η in [0, 1]) or
                ``"dpm++"`` (DPM-Solver++(2M), η = 0); eta: DDIM noise scale.
            generator: draws ``U_K`` and (η > 0) the per-step noise, in that order, each step
                one ``[B, N, 2]`` draw; must be on the tensors' device.
            noise: optional ``U_K [B, N, 2]``; step_noise: optional ``[S, B, N, 2]``.
            copies: C samples of every state: the CNN and the encoder run once per state, the
                decoder on C copies of its memory; sample c of state b is row ``b * C + c`` of the
                result (and of ``noise`` / ``step_noise``, ``[B * C, N, 2]`` each).
        Padding rows of the result are 0.
        """
        solver = self.make_sampler(sampler, num_steps, eta, clip_x0)
        b, n = pos_m.shape[:2]
        memory, mask = self.encode(obs, pos_m, valid)
        if copies > 1:
            memory, mask, pos_m = (t.repeat_interleave(copies, 0) for t in (memory, mask, pos_m))
            valid = valid.repeat_interleave(copies, 0) if valid is not None else None
        shape, dt = (b * copies, n, self.config.action_dim), self._state_dtype()
        if noise is None:
            noise = torch.randn(shape, generator=generator, device=memory.device, dtype=dt)

        def draw(i: int) -> Tensor:
            if step_noise is not None:
                return step_noise[i].to(dt)
            return torch.randn(shape, generator=generator, device=memory.device, dtype=dt)

        x = self._sample_loop(memory, pos_m, mask, noise.to(dt), solver, draw)
        if valid is not None:
            x = x * valid.unsqueeze(-1).to(x.dtype)
        return x

    @torch.no_grad()
    def sample_decentralized(self, obs: Tensor, pos_m: Tensor, num_steps: int = DEFAULT_SAMPLING_STEPS,
                             eta: float = 0.0, generator: torch.Generator | None = None,
                             valid: Tensor | None = None, noise: Tensor | None = None,
                             step_noise: Tensor | None = None, independent_noise: bool = False,
                             dedupe: bool = True, clip_x0: float | None = None,
                             sampler: str = DEFAULT_SAMPLER, copies: int = 1) -> Tensor:
        """Decentralized sampling: ``obs [N, 4, 32, 32]``, ``pos_m [N, 2]`` -> ``actions_norm [N, 2]``
        (a leading batch dimension ``[B, N, ...]`` is accepted too).

        What each robot does, as in the paper's Fig. 1: robot j computes its own token
        ``[z_j, p_j]`` (its CNN on its own observation, its neighbourhood offset) and shares it with
        the robots in range. Robot i then runs the encoder once and the decoder S times on the tokens
        of its neighbourhood ``M_i`` (itself + the robots in row i of the attention mask, with the
        mask recomputed among just those robots) and keeps only its own action.

        Layout (nothing loops over robots): the ``sum_i |M_i|`` real tokens of all neighbourhoods (of
        all B swarms) are packed, each neighbourhood whole, into rows of ``row_len`` tokens
        (:attr:`decentralized_row_tokens`, or a multiple of it that holds the largest neighbourhood;
        best-fit decreasing, :func:`madp.models.packing.pack_rows`), ``[R, row_len, ...]``, and attention
        is block-diagonal within a row (:func:`packed_neighbourhood_mask`), so it never mixes two
        neighbourhoods. Per-token layers run on the real tokens plus the few free slots the rows leave,
        and attention costs ``row_len`` per token rather than the whole swarm's token count.

        Noise: by default the noise of robot j is the same in every neighbourhood that contains j
        (``U_K`` and each step's noise are drawn once per swarm, ``[B, N, 2]``, and gathered), as if
        the robots derived each other's noise from a shared seed and robot id. Where neighbourhoods
        are the whole swarm the result equals :meth:`sample` with the same generator/noise.
        ``independent_noise=True`` draws every token's noise separately, ``[B, T, 2]`` per draw
        (``noise`` / ``step_noise`` are then not accepted).

        ``dedupe`` (only with shared noise): robots whose neighbourhoods are the same set of robots
        would run exactly the same computation (the model is permutation equivariant), so each
        distinct neighbourhood is computed once and every member reads its own action from it.
        Results equal ``dedupe=False`` up to float rounding; in a fully connected swarm this is N
        times less work.

        ``copies`` C: C samples of every state, each with its own noise (``noise`` / ``step_noise``
        ``[B * C, N, 2]``, sample c of state b in row ``b * C + c``, as is the result): tokens,
        packing and encoder run once per state, the decoder on C copies of every packed row
        (batched form only).
        """
        solver = self.make_sampler(sampler, num_steps, eta, clip_x0)
        single = pos_m.dim() == 2
        if single and copies > 1:
            raise ValueError("copies > 1 takes the batched form: obs [B, N, 4, S, S], pos_m [B, N, 2]")
        if single:
            obs, pos_m = obs.unsqueeze(0), pos_m.unsqueeze(0)
            valid = valid.unsqueeze(0) if valid is not None else None
            noise = noise.unsqueeze(0) if noise is not None else None
            step_noise = step_noise.unsqueeze(1) if step_noise is not None else None
        if independent_noise and (noise is not None or step_noise is not None):
            raise ValueError("noise/step_noise are swarm-level; they cannot be combined with independent_noise")
        b, n = pos_m.shape[:2]
        dev = pos_m.device
        if valid is None:
            valid = torch.ones(b, n, dtype=torch.bool, device=dev)
        valid = valid.to(torch.bool)
        mask = self.attention_mask(pos_m, valid)
        tokens = self.embed_tokens(obs, pos_m, mask, valid)  # [B, N, 34], one per robot
        view = (b, n, n)  # every ego holds every robot's own token and position
        out = self.sample_views(tokens.unsqueeze(1).expand(*view, tokens.shape[-1]), pos_m.unsqueeze(1).expand(*view, 2),
                                mask, valid, num_steps=num_steps, eta=eta, generator=generator, noise=noise,
                                step_noise=step_noise, independent_noise=independent_noise, dedupe=dedupe,
                                solver=solver, copies=copies)
        return out[0] if single else out

    @torch.no_grad()
    def sample_views(self, tokens_v: Tensor, pos_v: Tensor, member: Tensor, valid: Tensor, num_steps: int,
                     eta: float = 0.0, generator: torch.Generator | None = None, noise: Tensor | None = None,
                     step_noise: Tensor | None = None, independent_noise: bool = False, dedupe: bool = True,
                     key: Tensor | None = None, solver=None, sampler: str = DEFAULT_SAMPLER, copies: int = 1) -> Tensor:
        """Decentralized sampling from what each robot holds: ego i of swarm b runs the encoder and
        the decoder on its neighbourhood ``member[b, i]`` (``[B, N, N]`` bool, itself included), with
        the tokens ``tokens_v[b, i, j]`` ``[B, N, N, 34]`` and positions ``pos_v[b, i, j]`` ``[B, N, N, 2]``
        it holds of each member, and keeps its own action -> ``actions_norm [B * C, N, 2]``.
        ``key [B, N, N]`` (> 0 at members): egos share one computation only where their rows of
        ``key`` are equal (default: where their members are; then every ego must hold the same data
        of each robot). :meth:`sample_decentralized` (every robot's true state) is this with every
        ego holding every robot's own token and position. Noise and ``copies`` as there."""
        solver = solver or self.make_sampler(sampler, num_steps, eta, None)
        b, n = valid.shape
        dev = pos_v.device
        packed = pack_neighbourhoods(member, valid, self.decentralized_row_tokens, dedupe and not independent_noise,
                                     key)
        pos_p = packed.pack_view(pos_v)
        mask_p = packed_neighbourhood_mask(pos_p, self.config.comm_radius_m, packed.valid, packed.group)
        rope, bias = self._sampling_rope(pos_p), attention_bias(mask_p, self.dtype)  # for encoder and decoder
        memory = self.encode_tokens(packed.pack_view(tokens_v), pos_p, bias, rope)
        memory_kv, rope, bias = self._copies_context(memory, rope, bias, copies)

        def pack_copies(t: Tensor) -> Tensor:  # [B * C, N, A] -> [R * C, row_len, A]
            return packed.pack(t.unflatten(0, (b, copies)).transpose(1, 2)).transpose(1, 2).flatten(0, 1)

        dt = self._state_dtype()
        swarm_shape = (b * copies, n, self.config.action_dim)
        packed_shape = (packed.rows * copies, packed.row_len, self.config.action_dim)
        if independent_noise:
            x = torch.randn(packed_shape, generator=generator, device=dev, dtype=dt)

            def draw(i: int) -> Tensor:
                return torch.randn(packed_shape, generator=generator, device=dev, dtype=dt)
        else:
            if noise is None:
                noise = torch.randn(swarm_shape, generator=generator, device=dev, dtype=dt)
            x = pack_copies(noise.to(dt))

            def draw(i: int) -> Tensor:
                if step_noise is not None:
                    return pack_copies(step_noise[i].to(dt))
                return pack_copies(torch.randn(swarm_shape, generator=generator, device=dev, dtype=dt))

        x = self._denoise_loop(memory_kv, rope, bias, x, solver, draw).unflatten(0, (packed.rows, copies))
        own = packed.own(x.transpose(1, 2))  # each ego's own action [B * N, C, A]
        out = own.reshape(b, n, copies, -1).transpose(1, 2).flatten(0, 1)  # [B * C, N, A]
        return out * valid.repeat_interleave(copies, 0).unsqueeze(-1).to(x.dtype)
