"""``madp bench infer --roofline``: FLOPs, bytes and time of one decentralized MADP control step, by
part, against this machine's measured matmul peak (fp32 and bf16).

The step is the evaluation default's (:class:`madp.policies.SamplingSettings`: DPM-Solver++(2M) at
S = 3, K = 4 candidates per robot kept by ``explore``) for one swarm of the ``uniform`` suite (N = 32),
at two states: its start, and after ``after_steps`` steps of the clairvoyant expert (neighbourhoods
change as the swarm spreads). The parts:

* ``observations``: the simulator builds ``O [N, 4, 32, 32]`` (numpy/numba, :meth:`CoverageEnv.observations`);
* ``perception``: every robot's CNN and its token (:meth:`MADP.embed_tokens`);
* ``masks``: the attention mask (its component closure: ceil(log2 N) matmuls of ``[N, N]``), the
  packing of the neighbourhoods (:mod:`madp.models.packing`) and their packed mask;
* ``encoder``: Psi_E over the packed rows, once;
* ``denoiser``: the decoder's cross-attention K/V of every packed row (once, then repeated for the K
  copies), the time embedding of the S steps, and S passes of Psi_D over the K copies of every packed row;
* ``selection``: the rule's choice among the K candidates (:mod:`madp.robot.choice`);
* ``other``: the whole step (:meth:`MADPPolicy.act_batch`, timed apart) less the parts: the frame's
  transform, the noise, speed clipping, Python.

**FLOPs** of the model parts are counted analytically from the model's config and the packed layout
(every slot of every packed row is computed, padding tails included): 2·m·k·n per matmul,
2·B·C_out·C_in·k²·H·W per convolution, 4·B·H·L_q·L_k·D per attention; what ``torch.utils.flop_counter``
counts (tested equal); element-wise work (norms, activations, softmax, RoPE) is not counted. Those of
``observations`` and ``selection`` are the arithmetic of their kernels' inner loops: the banded
resize of each robot's sensed window (2 per tap), the boundary maps' products, ~10 per robot pair for
the neighbour maps; the block sums of each robot's window (1 per cell), the prior (2 per block), the
local cell cost (5 per block and neighbour or candidate distance, 2 per block and candidate
accumulated: an upper bound).

**Bytes** (the model): every matmul-class op reads its weights, bias and inputs (an attention mask
too) once and writes its output once, at 4 bytes a float32 (1 a bool mask); element-wise ops are taken
as fused (a lower bound of the traffic, so FLOP/B is an upper bound). ``observations``: each robot's
sensed window read once, ``O`` and its three stacked temporaries written (and these read) once.
``selection``: each robot's window read once by the block sums, its [64, 64] float64 blocks written
once and read by the prior and the cell cost. Bytes are those of the fp32 run.

**Time**: the median of ``repeats`` calls of each part alone (one untimed call first), fp32, and under
``torch.autocast(dtype=bfloat16)`` for the model parts and the whole step. **Peaks**: float32 and bfloat16
``torch.matmul`` at the model's shapes (``[2048, d] @ [d, 4d]`` and back) and a large square one, on
the same threads, before and after the timing (the better of the two: load only slows a machine down);
the highest of each dtype is its peak; the copy bandwidth of a 64 MiB tensor gives
the roofline's slope (bound: ``memory`` below the ridge FLOP/B = fp32 peak / bandwidth). With
``device="cuda"`` the model parts run and are compared there (the GPU's own peaks; observations and
selection stay on the CPU, against the CPU's).
"""

from __future__ import annotations

import math
import os
import statistics
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from madp.errors import SettingError
from madp.models.bench import torch_threads, timed, matmul_flops_per_s

#: The parts of a control step, in table order; :data:`MODEL_PARTS` run in torch (on ``device``).
PARTS = ("observations", "perception", "masks", "encoder", "denoiser", "selection")
MODEL_PARTS = ("perception", "masks", "encoder", "denoiser")
#: CPU features worth naming beside a matmul peak (x86 ``/proc/cpuinfo`` flags).
CPU_FLAGS = ("avx2", "fma", "f16c", "avx512f", "avx512_vnni", "avx512_bf16", "avx512_fp16", "avx_vnni",
             "amx_tile", "amx_bf16", "amx_int8")
F32 = 4


@dataclass(frozen=True)
class Layout:
    """The packed layout of one step: ``robots`` N (the mask's side), ``units`` distinct neighbourhoods,
    ``tokens`` real tokens (Σ |M_u|), ``rows`` × ``row_len`` packed slots, K ``copies``, S ``steps``."""

    robots: int
    units: int
    tokens: int
    rows: int
    row_len: int
    copies: int
    steps: int


def _linear(rows: int, k: int, n: int) -> np.ndarray:
    """(FLOPs, bytes) of a biased ``[rows, k] @ [k, n]``."""
    return np.array([2 * rows * k * n, F32 * (k * n + n + rows * k + rows * n)])


def _attention(batch: int, length: int, d: int, mask_bytes: int) -> np.ndarray:
    """(FLOPs, bytes) of attention over ``batch`` rows of ``length`` tokens, width d (all heads), with a
    ``[batch, 1, length, length]`` mask of ``mask_bytes`` per element."""
    return np.array([4 * batch * length * length * d, F32 * 4 * batch * length * d + mask_bytes * batch * length ** 2])


def model_costs(cfg, lay: Layout) -> dict[str, tuple[int, int]]:
    """(FLOPs, bytes) of each model part (:data:`MODEL_PARTS`) of one decentralized step on ``lay``
    (module docstring) for the MADP config ``cfg``."""
    n, d, r, a = lay.robots, cfg.d_model, cfg.mlp_ratio, cfg.action_dim
    cost = {}
    size, c_in, k = cfg.obs_size, cfg.obs_channels, cfg.cnn_kernel
    cnn = np.zeros(2, dtype=np.int64)
    for c_out in cfg.cnn_channels:
        out = (size + 2 * cfg.cnn_padding - k) // cfg.cnn_stride + 1
        bias = c_out if cfg.cnn_norm != "batch" else 0
        cnn += [2 * n * c_out * c_in * k * k * out * out,
                F32 * (c_out * c_in * k * k + bias + n * c_in * size * size + n * c_out * out * out)]
        c_in, size = c_out, out
    cost["perception"] = cnn + _linear(n, c_in * size * size, cfg.z_dim)
    closure = max(1, math.ceil(math.log2(max(n, 2))))
    cost["masks"] = closure * np.array([2 * n ** 3, F32 * 3 * n * n])
    slots, L = lay.rows * lay.row_len, lay.row_len
    enc = _linear(slots, d, 3 * d) + _attention(lay.rows, L, d, 1) + _linear(slots, d, d)
    enc += _linear(slots, d, r * d) + _linear(slots, r * d, d)
    cost["encoder"] = _linear(slots, cfg.token_dim, d) + cfg.n_enc_layers * enc
    rc = lay.rows * lay.copies
    m = rc * L
    dt = cfg.time_embed_dim or d
    once = _linear(lay.steps, dt, 4 * d) + _linear(lay.steps, 4 * d, d) + cfg.n_dec_layers * _linear(slots, d, 2 * d)
    dec = _linear(m, d, 3 * d) + _linear(m, d, d) + _linear(m, d, d) + _linear(m, d, d)
    dec += 2 * _attention(rc, L, d, F32) + _linear(m, d, r * d) + _linear(m, r * d, d)
    per_pass = _linear(m, a, d) + cfg.n_dec_layers * dec + _linear(m, d, a)
    cost["denoiser"] = once + lay.steps * per_pass
    return {p: (int(c[0]), int(c[1])) for p, c in cost.items()}


def observation_costs(env) -> tuple[int, int]:
    """(FLOPs, bytes) of :meth:`CoverageEnv.observations` at ``env``'s state (module docstring)."""
    from madp.sim.observations import resize_band
    from madp.sim.robot_maps import robot_cells

    maps, p = env.maps, env.params
    s, o, n = maps.local_size, p.obs_size, env.num_robots
    first, taps, _ = resize_band(s, o)
    start = robot_cells(env.estimates_m()) - s // 2 + maps.pad  # [N, 2] each window's corner, padded
    x_lo = np.clip(maps.seen_lo[:, 0] - start[:, 0], 0, s)  # the sensed box, in window coordinates
    x_hi = np.clip(maps.seen_hi[:, 0] - start[:, 0], x_lo, s)
    y_len = np.clip(maps.seen_hi[:, 1] - start[:, 1], 0, s) - np.clip(maps.seen_lo[:, 1] - start[:, 1], 0, s)
    y_len = np.maximum(y_len, 0)
    t = np.arange(int(taps.max()))
    rows = (first[:, None] + t)[None]  # [1, O, T] window row of each tap
    used = (t < taps[:, None])[None] & (rows >= x_lo[:, None, None]) & (rows < x_hi[:, None, None])
    resize = 2 * int((used.sum((1, 2)) * y_len).sum()) + 2 * n * int(taps.sum()) * o
    boundary = 2 * 2 * n * s * o + 2 * n * o * o
    neighbours = 10 * n * n
    window = int(((x_hi - x_lo) * y_len).sum())
    return resize + boundary + neighbours, F32 * window + F32 * n * 4 * o * o * 3


def selection_costs(env, select: str, candidates: int) -> tuple[int, int]:
    """(FLOPs, bytes) of rule ``select`` choosing among ``candidates`` K at ``env``'s state (module
    docstring): ``none`` and the rules that rank, robot by robot, on the mean of the explored blocks or on
    the true map (not those that read a learned network: it is timed, not counted)."""
    from madp.robot.choice import local_views
    from madp.selection import RULES, weigh

    n, k = env.num_robots, candidates
    r = RULES.get(select)
    if r is not None and not r.ranks and not r.bound:
        return 0, 0
    if r is None or not r.ranks or r.needs or r.joint:
        raise SettingError("select", f"the roofline counts none and the rules that rank on the explored mean or the "
                                     f"true map, got {select!r}")
    views = local_views(env, true_map=r.sees == "true map")
    s, g = env.maps.local_size, views.weights.shape[1]
    flops, traffic = n * s * s, F32 * n * s * s + 8 * n * g * g
    if r.weigh is not None:  # the explored blocks' mean on the unexplored ones
        views = weigh(r, env.maps, views)
        flops, traffic = flops + 2 * n * g * g, traffic + (8 + 1 + 8) * n * g * g
    blocks = (views.weights != 0).sum((1, 2))
    flops += int((blocks * (5 * views.valid.sum(1) + 7 * k)).sum())
    return int(flops), int(traffic + 8 * n * g * g)


def cpu_features() -> dict:
    """The CPU's name, the :data:`CPU_FLAGS` it has (``/proc/cpuinfo``), torch's CPU capability and threads."""
    flags, name = set(), ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "flags" and not flags:
                flags = set(value.split())
            if key.strip() == "model name" and not name:
                name = value.strip()
    except OSError:  # not Linux: flags unknown
        pass
    has = [f for f in CPU_FLAGS if f in flags]
    bf16 = "AMX" if "amx_bf16" in has else "AVX-512 BF16" if "avx512_bf16" in has else "none (converted to fp32)"
    return {"model": name, "flags": has, "bf16_matmul": bf16, "threads": torch.get_num_threads(),
            "torch_capability": torch.backends.cpu.get_cpu_capability()}


def measure_peaks(cfg, device: str = "cpu", rows: int = 2048, square: int | None = None) -> dict:
    """Matmul FLOP/s (float32, bfloat16) at the model's shapes ``[rows, d] @ [d, 4d]`` and back and a
    ``square``-sided one (default 2048 on the CPU, 8192 on a GPU; bfloat16 at most 512 on a CPU without
    bfloat16 instructions, where it is converted and a 2048-sided one takes about a minute), each dtype's
    peak (the highest), and the copy bandwidth (bytes read + written per second, 64 MiB)."""
    d, h = cfg.d_model, cfg.mlp_ratio * cfg.d_model
    cpu = torch.device(device).type != "cuda"
    square = square or (2048 if cpu else 8192)
    converted = cpu and cpu_features()["bf16_matmul"].startswith("none")
    out: dict = {"device": device, "matmul": []}
    for dtype in ("float32", "bfloat16"):
        side = min(square, 512) if dtype == "bfloat16" and converted else square
        for m, k, n in [(rows, d, h), (rows, h, d), (side, side, side)]:
            reps = max(3, min(100, round(2e9 / (2 * m * k * n))))
            rate = matmul_flops_per_s(device=device, shape=(m, k, n), dtype=getattr(torch, dtype), reps=reps)
            out["matmul"].append({"dtype": dtype, "shape": [m, k, n], "flops_per_s": rate})
        out[f"peak_{dtype}"] = max(x["flops_per_s"] for x in out["matmul"] if x["dtype"] == dtype)
    a = torch.empty(16 << 20, device=device)
    b = torch.empty_like(a)
    out["copy_bytes_per_s"] = 2 * a.numel() * F32 / statistics.median(timed(lambda: b.copy_(a), 2, 10, device))
    out["ridge_flop_per_byte"] = out["peak_float32"] / out["copy_bytes_per_s"]
    return out


def roofline_states(after_steps: int = 300, index: int = 0) -> list[tuple[str, object]]:
    """Environment ``index`` of the ``uniform`` suite at its start and after ``after_steps`` steps of the
    clairvoyant expert."""
    from madp.eval.suites import suite_envs
    from madp.sim import ClairvoyantCVT, CoverageEnv

    scenario = suite_envs("uniform", index + 1)[index].scenario()
    later, expert = CoverageEnv(scenario), ClairvoyantCVT()
    for _ in range(after_steps):
        later.step(expert(later))
    return [("start", CoverageEnv(scenario)), (f"after {after_steps} expert steps", later)]


def model_parts(model, obs: torch.Tensor, pos: torch.Tensor, sampling) -> tuple[dict, Layout]:
    """The model parts of :meth:`MADP.sample_decentralized` with ``copies`` K for ``obs [1, N, 4, S, S]``,
    ``pos [1, N, 2]``, each a call of the model's own steps on the previous part's result (computed
    once here), and the packed layout they run on."""
    from madp.models.attention_mask import packed_neighbourhood_mask
    from madp.models.packing import pack_neighbourhoods
    from madp.models.transformer import attention_bias

    b, n = pos.shape[:2]
    k, steps = sampling.candidates, sampling.sampling_steps
    valid = torch.ones(b, n, dtype=torch.bool, device=pos.device)
    with torch.inference_mode():
        mask = model.attention_mask(pos, valid)
        tokens = model.embed_tokens(obs, pos, mask, valid)

        def masks():
            packed = pack_neighbourhoods(model.attention_mask(pos, valid), valid, model.decentralized_row_tokens, True)
            view = (b, n, n)
            pos_p = packed.pack_view(pos.unsqueeze(1).expand(*view, 2))
            tok_p = packed.pack_view(tokens.unsqueeze(1).expand(*view, tokens.shape[-1]))
            return packed, pos_p, tok_p, packed_neighbourhood_mask(pos_p, model.config.comm_radius_m, packed.valid,
                                                                   packed.group)

        packed, pos_p, tok_p, mask_p = masks()
        memory = model.encode_tokens(tok_p, pos_p, mask_p)
    noise = torch.randn(packed.rows * k, packed.row_len, model.config.action_dim,
                        generator=torch.Generator().manual_seed(0)).to(pos.device)

    def denoiser():
        rope, bias = model._sampling_rope(pos_p), attention_bias(mask_p, model.dtype)
        solver = model.make_sampler(sampling.sampler, steps, sampling.eta)
        return model._denoise_loop(*model._copies_context(memory, rope, bias, k), noise.to(model.dtype), solver,
                                   lambda i: torch.randn_like(noise))

    parts = {"perception": lambda: model.embed_tokens(obs, pos, mask, valid), "masks": masks,
             "encoder": lambda: model.encode_tokens(tok_p, pos_p, mask_p), "denoiser": denoiser}
    lay = Layout(n, int(packed.unit_rows.shape[0]), int(packed.unit.numel()), packed.rows, packed.row_len, k, steps)
    return parts, lay


def _load() -> float | None:
    """The 1-minute load average (None where the system does not tell)."""
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def _median_s(fn, repeats: int, device: str, bf16: bool = False) -> float:
    dev = torch.device(device).type
    with torch.inference_mode(), torch.autocast(dev, dtype=torch.bfloat16, enabled=bf16):
        return statistics.median(timed(fn, 1, repeats, device))


def _rate(flops: int, time_s: float, peak: float) -> dict:
    """Achieved FLOP/s and its fraction of ``peak``; ``flag`` says why a fraction is missing or above 1."""
    if flops == 0:
        flag = "no FLOPs counted" + ("; negative: the parts' medians exceed the step's (noise)" if time_s < 0 else "")
        return {"time_s": time_s, "flops_per_s": None, "fraction": None, "flag": flag}
    rate = flops / time_s
    flag = "above the measured peak (noise or a peak measured under load)" if rate > peak else None
    return {"time_s": time_s, "flops_per_s": rate, "fraction": rate / peak, "flag": flag}


def measure_state(model, env, sampling, repeats: int = 5, device: str = "cpu", seed: int = 0) -> dict:
    """Every part's (and the whole step's) FLOPs, bytes and median time (``float32``, ``bfloat16``:
    seconds, None where a part does not run in torch) at ``env``'s state; :func:`add_rates` adds the rates."""
    from madp.policies import MADPPolicy, noise_generator
    from madp.policies.select import select_actions
    from madp.policies.swarm import swarm_tensors

    obs, pos = swarm_tensors([env], torch.device(device))
    parts, lay = model_parts(model, obs, pos, sampling)
    costs = {**model_costs(model.config, lay), "observations": observation_costs(env),
             "selection": selection_costs(env, sampling.select, sampling.candidates)}
    rng = np.random.default_rng(seed)
    u_max = env.params.max_speed_mps
    cand = np.clip(rng.normal(0.0, u_max / 2, (sampling.candidates, env.num_robots, 2)), -u_max, u_max)
    host = {"observations": env.observations, "selection": lambda: select_actions(sampling.select, env, cand)}
    policy = MADPPolicy(model, "decentralized", sampling, device=device)
    step = lambda: policy.act_batch([env], [noise_generator(seed)])  # noqa: E731
    rows = []
    for part in PARTS:
        on, torch_part = (device, True) if part in MODEL_PARTS else ("cpu", False)
        fn = parts[part] if torch_part else host[part]
        rows.append({"part": part, "on": on, "flops": costs[part][0], "bytes": costs[part][1],
                     "float32": _median_s(fn, repeats, on), "bfloat16": _median_s(fn, repeats, on, True) if torch_part else None})
    whole = {dtype: _median_s(step, repeats, device, dtype == "bfloat16") for dtype in ("float32", "bfloat16")}
    # bf16: the host parts at their fp32 times
    rest = {dtype: whole[dtype] - sum(r[dtype] or r["float32"] for r in rows) for dtype in whole}
    rows.append({"part": "other", "on": device, "flops": 0, "bytes": 0, **rest})
    rows.append({"part": "control step", "on": device, "flops": sum(r["flops"] for r in rows),
                 "bytes": sum(r["bytes"] for r in rows), **whole})
    return {"layout": asdict(lay), "parts": rows}


def merge_peaks(a: dict, b: dict) -> dict:
    """Two :func:`measure_peaks` of one device (before and after the timing) -> the best of each figure."""
    out = {**a, "matmul": [{**x, "flops_per_s": max(x["flops_per_s"], y["flops_per_s"])}
                           for x, y in zip(a["matmul"], b["matmul"])]}
    for key in ("peak_float32", "peak_bfloat16", "copy_bytes_per_s"):
        out[key] = max(a[key], b[key])
    out["ridge_flop_per_byte"] = out["peak_float32"] / out["copy_bytes_per_s"]
    return out


def add_rates(state: dict, peaks: dict) -> None:
    """Each row of a :func:`measure_state` result gets its FLOP/B, its bound (``memory`` below the ridge)
    and, per dtype, its time as ``{time_s, flops_per_s, fraction, flag}`` against that dtype's peak."""
    for r in state["parts"]:
        p = peaks[r["on"]]
        r["flop_per_byte"] = r["flops"] / max(r["bytes"], 1)
        r["bound"] = "" if r["part"] in ("other", "control step") else (
            "memory" if r["flop_per_byte"] < p["ridge_flop_per_byte"] else "compute")
        for dtype in ("float32", "bfloat16"):
            if r[dtype] is not None:
                r[dtype] = _rate(r["flops"], r[dtype], p[f"peak_{dtype}"])


def roofline(checkpoint: str | None = None, after_steps: int = 300, repeats: int = 5, threads: int | None = 2,
             device: str = "cpu", index: int = 0, square: int | None = None) -> dict:
    """The roofline of the evaluation default's control step (module docstring; a default rule that reads
    a learned network is counted as its fallback, ``explore`` for ``critic``) at both states of
    :func:`roofline_states`; the peaks are measured before and after the timing (the best of the two).
    The model: ``checkpoint``, else the shipped one, else an untrained ``cpu`` preset (FLOPs, bytes and
    times do not depend on the weights)."""
    from madp.models import MADP, madp_config
    from madp.policies import SamplingSettings, load, shipped_checkpoint

    path = checkpoint or (str(shipped_checkpoint("madp")) if shipped_checkpoint("madp") else None)
    torch.manual_seed(0)
    model = (load(path, "madp", device)[0] if path else MADP(madp_config("cpu")).to(device)).eval()
    sampling = SamplingSettings().fitted(())  # a learned network's part is timed, not counted: its fallback's
    load_before = _load()
    devices = ["cpu"] + ([device] if torch.device(device).type != "cpu" else [])
    with torch_threads(threads):
        before = {d: measure_peaks(model.config, d, square=square) for d in devices}
        states = [{"state": name, **measure_state(model, env, sampling, repeats, device)}
                  for name, env in roofline_states(after_steps, index)]
        peaks = {d: merge_peaks(before[d], measure_peaks(model.config, d, square=square)) for d in devices}
        machine = cpu_features()
    for st in states:
        add_rates(st, peaks)
    if torch.device(device).type == "cuda":
        machine["gpu"] = torch.cuda.get_device_name(torch.device(device))
    return {"checkpoint": path, "preset": model.config.preset, "device": device, "repeats": repeats,
            "sampling": sampling.as_dict(), "machine": machine, "peaks": peaks, "states": states,
            "load_average": {"before": load_before, "after": _load()}}


def _pct(x: dict | None) -> str:
    if x is None or x["fraction"] is None:
        return "-"
    return f"{100 * x['fraction']:.1f}%" + ("!" if x["flag"] else "")


def format_roofline(r: dict) -> list[str]:
    """The lines ``madp bench infer --roofline`` prints for a :func:`roofline` result."""
    s, m = r["sampling"], r["machine"]
    lines = [f"roofline of one decentralized MADP control step ({r['preset']} preset, {s['sampler']} S = "
             f"{s['sampling_steps']}, K = {s['candidates']}, {s['select']}; {r['device']}, {m['threads']} threads; "
             f"median of {r['repeats']}; 1-min load average {r['load_average']['before']} before, "
             f"{r['load_average']['after']} after)"]
    for dev, p in r["peaks"].items():
        mm = ", ".join(f"{'fp32' if x['dtype'] == 'float32' else 'bf16'} {'x'.join(map(str, x['shape']))} "
                       f"{x['flops_per_s'] / 1e9:.0f}" for x in p["matmul"])
        lines.append(f"peaks on {dev} (GFLOP/s, [m x k x n]): {mm}; copy {p['copy_bytes_per_s'] / 1e9:.1f} GB/s, "
                     f"ridge {p['ridge_flop_per_byte']:.1f} FLOP/B")
    lines.append(f"cpu: {m['model'] or '?'}; flags {' '.join(m['flags']) or 'none'}; bf16 matmul by {m['bf16_matmul']}; "
                 f"torch capability {m['torch_capability']}" + (f"; gpu: {m['gpu']}" if m.get("gpu") else ""))
    for st in r["states"]:
        lay = st["layout"]
        pad = 1 - lay["tokens"] / (lay["rows"] * lay["row_len"])
        lines.append(f"state: {st['state']}: N = {lay['robots']}, {lay['units']} neighbourhoods, {lay['tokens']} tokens "
                     f"in {lay['rows']} rows of {lay['row_len']} ({100 * pad:.0f}% padding), x K = {lay['copies']} "
                     f"copies x S = {lay['steps']} in the denoiser")
        lines.append(f"{'part':<14}{'on':<6}{'MFLOP':>9}{'MB':>8}{'FLOP/B':>8}{'bound':>9}"
                     f"{'fp32 ms':>9}{'GFLOP/s':>9}{'%peak':>8}{'bf16 ms':>9}{'GFLOP/s':>9}{'%peak':>8}")
        for x in st["parts"]:
            cols = []
            for dtype in ("float32", "bfloat16"):
                v = x[dtype]
                rate = "-" if v is None or v["flops_per_s"] is None else f"{v['flops_per_s'] / 1e9:.1f}"
                ms = "-" if v is None else f"{1e3 * v['time_s']:.2f}"
                cols.append(f"{ms:>9}{rate:>9}{_pct(v):>8}")
            lines.append(f"{x['part']:<14}{x['on']:<6}{x['flops'] / 1e6:>9.2f}{x['bytes'] / 1e6:>8.2f}"
                         f"{x['flop_per_byte']:>8.1f}{x['bound']:>9}" + "".join(cols))
    lines.append("MFLOP: matmul-class FLOPs (model parts) or the kernels' arithmetic (observations, selection); MB: "
                 "operands read + results written once (fp32); %peak: of the dtype's highest measured matmul; "
                 "! above it; bf16: the model parts under autocast, the host parts as in fp32")
    return lines
