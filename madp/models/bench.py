"""Micro-benchmarks of the models on random inputs (no data, no simulator).

* :func:`matmul_flops_per_s`, :func:`count_flops`, :func:`count_bytes`: this machine's matmul FLOP/s
  (float32 or bfloat16, square or at a model's shapes), the FLOPs of a function
  (``torch.utils.flop_counter``) and the bytes its matmul-class ops move, for ``madp bench train``
  (:mod:`madp.training.bench`), which times real training steps, and the control step's roofline
  (:mod:`madp.inference_bench.roofline`).
* :func:`bench_infer`: median latency of one MADP control step (CNN + encoder once, decoder S times)
  in decentralized or centralized-masked mode.

Run ``python -m madp.models.bench`` for the default table.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from typing import Any

import torch

from .config import lpac_config, madp_config
from .madp import MADP

__all__ = ["bench_infer", "count_bytes", "count_flops", "matmul_flops_per_s", "random_swarm", "sync_device", "timed",
           "torch_threads"]


def random_swarm(batch: int, num_robots: int, world: float = 1024.0, generator: torch.Generator | None = None,
                 device: torch.device | str = "cpu") -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random ``obs [B, N, 4, 32, 32]``, ``pos_m [B, N, 2]`` uniform over the world, ``actions [B, N, 2]``."""
    obs = torch.rand(batch, num_robots, 4, 32, 32, generator=generator).to(device)
    pos = (torch.rand(batch, num_robots, 2, generator=generator) * world).to(device)
    act = torch.randn(batch, num_robots, 2, generator=generator).to(device)
    return obs, pos, act


def matmul_flops_per_s(n: int = 2048, reps: int = 10, device: torch.device | str = "cpu",
                       shape: tuple[int, int, int] | None = None, dtype: torch.dtype = torch.float32) -> float:
    """Median FLOP/s of a ``dtype`` matmul on this machine: ``n x n @ n x n`` (2 n^3 FLOPs), or
    ``[m, k] @ [k, p]`` (2 m k p FLOPs) for ``shape = (m, k, p)``; two untimed calls first."""
    m, k, p = shape or (n, n, n)
    a = torch.randn(m, k, device=device).to(dtype)
    b = torch.randn(k, p, device=device).to(dtype)
    times = timed(lambda: a @ b, 2, reps, device)
    return 2 * m * k * p / statistics.median(times)


class torch_threads:
    """Temporarily set torch's intra-op thread count (None: leave it)."""

    def __init__(self, n: int | None):
        self.n, self.before = n, torch.get_num_threads()

    def __enter__(self) -> None:
        if self.n is not None:
            torch.set_num_threads(self.n)

    def __exit__(self, *exc: object) -> None:
        torch.set_num_threads(self.before)


def sync_device(device: torch.device | str) -> None:
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()


def timed(fn, warmup: int, repeats: int, device) -> list[float]:
    """Wall seconds of ``repeats`` calls of ``fn`` after ``warmup`` untimed ones (device-synchronised)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        sync_device(device)
        t = time.perf_counter()
        fn()
        sync_device(device)
        times.append(time.perf_counter() - t)
    return times


def count_flops(fn) -> int:
    """FLOPs of ``fn()`` by ``FlopCounterMode``. Its default table knows the CUDA attention kernels but
    not the CPU flash-attention op that ``scaled_dot_product_attention`` dispatches to here, so that
    op (forward and backward) is mapped to the same formulas."""
    from torch.utils import flop_counter as fc

    def fwd_flops(q, k, v, *args, out_shape=None, **kwargs) -> int:  # receives shapes
        return fc.sdpa_flop_count(q, k, v)

    def bwd_flops(grad_out, q, k, v, *args, out_shape=None, **kwargs) -> int:
        return fc.sdpa_backward_flop_count(grad_out, q, k, v)

    aten = torch.ops.aten
    custom = {}
    if hasattr(aten, "_scaled_dot_product_flash_attention_for_cpu"):
        custom[aten._scaled_dot_product_flash_attention_for_cpu] = fwd_flops
    if hasattr(aten, "_scaled_dot_product_flash_attention_for_cpu_backward"):
        custom[aten._scaled_dot_product_flash_attention_for_cpu_backward] = bwd_flops
    with fc.FlopCounterMode(display=False, custom_mapping=custom) as counter:
        fn()
    return int(counter.get_total_flops())


#: The ops whose operands :func:`count_bytes` counts: matmuls, convolutions and attention (the ops
#: ``FlopCounterMode`` counts FLOPs of), at whichever level the dispatcher shows them.
_BYTE_OPS = ("linear", "addmm", "mm", "bmm", "matmul", "conv2d", "convolution", "scaled_dot_product_attention",
             "_scaled_dot_product_flash_attention_for_cpu")


def count_bytes(fn) -> int:
    """Bytes the matmul-class ops of ``fn()`` read and write (:data:`_BYTE_OPS`): every tensor operand
    (weights, bias, inputs, an attention mask) once and the first output once, at its dtype's size.
    Element-wise ops (norms, activations, residual adds) are taken as fused into them: not counted."""
    from torch.utils._python_dispatch import TorchDispatchMode

    def size(t: object) -> int:
        return t.numel() * t.element_size() if isinstance(t, torch.Tensor) else 0

    class Counter(TorchDispatchMode):
        total = 0

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            out = func(*args, **(kwargs or {}))
            if func.overloadpacket.__name__ in _BYTE_OPS:
                first = out[0] if isinstance(out, (tuple, list)) else out
                Counter.total += sum(size(a) for a in [*args, *(kwargs or {}).values()]) + size(first)
            return out

    with Counter():
        fn()
    return Counter.total


def bench_infer(preset: str = "cpu", mode: str = "decentralized", num_steps: int = 50, num_robots: int = 32,
                repeats: int = 5, warmup: int = 1, eta: float = 0.0, layout: str = "uniform",
                dedupe: bool = True, device: torch.device | str = "cpu", seed: int = 0,
                threads: int | None = None, sampler: str = "ddim") -> dict[str, Any]:
    """Median latency of one MADP control step for one swarm of ``num_robots`` robots
    (``mode``: ``"decentralized"`` or ``"centralized"``) with ``sampler`` (``"ddim"`` / ``"dpm++"``) at
    ``num_steps`` steps.

    ``layout``: ``"uniform"`` over the 1024 m world (the usual launch; neighbourhoods of ~5-10
    robots) or ``"square"`` (SPEC §5's square launch, x, y in [115.25, 217.25]: everyone within
    r_c of everyone, the worst case for decentralized execution, M = N). ``dedupe`` is passed to
    :meth:`MADP.sample_decentralized` (False: every robot's neighbourhood is computed, even when
    several coincide). Also reports the largest and mean neighbourhood size (tokens per
    neighbourhood batch in decentralized mode). ``threads``: torch's intra-op threads for the run (None: the current setting).
    """
    with torch_threads(threads):
        return _bench_infer(preset, mode, num_steps, num_robots, repeats, warmup, eta, layout, dedupe, device, seed,
                            sampler)


def _bench_infer(preset: str, mode: str, num_steps: int, num_robots: int, repeats: int, warmup: int, eta: float,
                 layout: str, dedupe: bool, device: torch.device | str, seed: int, sampler: str) -> dict[str, Any]:
    if mode not in ("decentralized", "centralized"):
        raise ValueError("mode must be 'decentralized' or 'centralized'")
    torch.manual_seed(seed)
    g = torch.Generator().manual_seed(seed)
    model = MADP(madp_config(preset)).to(device).eval()
    obs, pos, _ = random_swarm(1, num_robots, generator=g, device=device)
    if layout == "square":
        pos = 115.25 + pos / 1024.0 * (217.25 - 115.25)
    elif layout != "uniform":
        raise ValueError("layout must be 'uniform' or 'square'")
    with torch.inference_mode():
        mask = model.attention_mask(pos)
        max_hood = int(mask.sum(-1).max())
        mean_hood = float(mask.sum(-1).float().mean())

    def run() -> None:
        with torch.inference_mode():
            if mode == "decentralized":
                model.sample_decentralized(obs[0], pos[0], num_steps=num_steps, eta=eta, dedupe=dedupe,
                                           sampler=sampler)
            else:
                model.sample(obs, pos, num_steps=num_steps, eta=eta, sampler=sampler)

    times = timed(run, warmup, repeats, device)
    return {
        "preset": preset, "mode": mode, "layout": layout, "dedupe": dedupe, "sampler": sampler, "num_steps": num_steps,
        "num_robots": num_robots,
        "threads": torch.get_num_threads(), "device": str(device),
        "latency_s": statistics.median(times), "latency_min_s": min(times), "latency_max_s": max(times),
        "max_neighbourhood": max_hood, "mean_neighbourhood": mean_hood,
    }


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description="madp model micro-benchmarks")
    p.add_argument("--preset", default="cpu")
    p.add_argument("--num-robots", type=int, default=32)
    p.add_argument("--threads", type=int, default=None)
    args = p.parse_args(argv)
    kw = dict(num_robots=args.num_robots, threads=args.threads)
    results = [
        bench_infer(args.preset, "decentralized", **kw),
        bench_infer(args.preset, "decentralized", layout="square", **kw),
        bench_infer(args.preset, "decentralized", layout="square", dedupe=False, **kw),
        bench_infer(args.preset, "centralized", **kw),
    ]
    for r in results:
        print(json.dumps(r))


if __name__ == "__main__":
    main()
