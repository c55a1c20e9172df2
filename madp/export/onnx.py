"""``madp export``: a MADP policy file as what one robot runs, ONNX graphs and one JSON file.

What a directory made by :func:`export_policy` holds (the robot runtime :mod:`madp.robot` reads it):

=====================  ====================================================================================
``perception.onnx``    the CNN: ``observation [R, 4, 32, 32]`` float32 -> ``z [R, z_dim]``
``encoder.onnx``       Psi_E: ``tokens [B, T, 34]``, ``positions_m [B, T, 2]`` float32, ``mask [B, T, T]`` bool
                       -> ``memory [B, T, d_model]``
``denoiser.onnx``      Psi_D and the head: ``noisy_actions [B, T, 2]``, ``step [B]`` int64, ``memory``,
                       ``positions_m``, ``mask`` -> ``eps [B, T, 2]`` (the predicted noise)
``map_prior.onnx``     with a ``value`` rule only: the policy file's learned map prior
                       (:class:`madp.models.map_prior.MapPrior`): ``windows [R, 3, H, W]`` float32 ->
                       ``density [R, H, W]`` (:mod:`madp.robot.prior`)
``critic.onnx``        with a ``critic`` rule only: the policy file's critic (:class:`madp.models.critic.Critic`):
                       ``windows [R, 5, H, H]``, ``neighbours [R, M, 3]`` float32 -> ``mass [R]``,
                       ``offset [R, 2]`` (:mod:`madp.robot.critic`)
``runtime.json``       what the loop around them needs (:func:`runtime_spec`) and each graph's sha256
=====================  ====================================================================================

T, the tokens of a neighbourhood, and the batch axes are dynamic. The sampling loop stays in plain code
(numpy, :mod:`madp.robot.runtime`), as diffusion policies are usually exported: the graphs hold only
the networks, the JSON the sampler's constants. ``mask[b, a, c]`` lets token a attend to token c
(:func:`madp.models.attention_mask.packed_neighbourhood_mask` of one neighbourhood).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import torch
from torch import Tensor, nn

from madp.io.checksum import sha256_file
from madp.errors import InputError, SettingError
from madp.io.atomic import atomic_path, write_json_atomic
from madp.io.lock import locked_dir
from madp.io.owned import foreign_files
from madp.policies.checkpoint import carried, load_learned, load_policy
from madp.policies.madp import SamplingSettings, check_sampling_steps
from madp.policies.select import GRID_M
from madp.selection import NEEDS, RULES
from madp.sim import SimParams

__all__ = ["FORMAT", "GRAPHS", "LEARNED_GRAPHS", "OPSET", "PRIOR_GRAPH", "export_critic", "export_policy", "export_graphs", "runtime_spec", "write_runtime"]

#: ``runtime.json``'s ``format``: the layout the runtime reads.
FORMAT = "madp-onnx-runtime/1"
#: The ONNX opset of the graphs.
OPSET = 17
#: The graphs, by role, and their file names.
GRAPHS = {"perception": "perception.onnx", "encoder": "encoder.onnx", "denoiser": "denoiser.onnx"}
#: The graph of the learned network a rule reads (:attr:`madp.selection.Rule.needs`), by that need:
#: ``{role: file name}``.
LEARNED_GRAPHS = {name: {n.key: f"{n.key}.onnx"} for name, n in NEEDS.items()}
#: The map prior's graph (the ``value`` rules only), by role, and its file name.
PRIOR_GRAPH = LEARNED_GRAPHS["map prior"]
RUNTIME_JSON = "runtime.json"


class _Perception(nn.Module):
    def __init__(self, model):
        super().__init__()
        self.cnn = model.cnn

    def forward(self, observation: Tensor) -> Tensor:
        return self.cnn(observation)


class _Encoder(nn.Module):
    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, tokens: Tensor, positions_m: Tensor, mask: Tensor) -> Tensor:
        return self.model.encode_tokens(tokens, positions_m, mask)


class _Denoiser(nn.Module):
    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, noisy_actions: Tensor, step: Tensor, memory: Tensor, positions_m: Tensor, mask: Tensor) -> Tensor:
        return self.model.denoise(noisy_actions, step, memory, positions_m, mask)


def _example(model, tokens: int = 3, batch: int = 2) -> dict[str, Tensor]:
    cfg = model.config
    pos = torch.rand(batch, tokens, 2) * cfg.comm_radius_m
    mask = torch.ones(batch, tokens, tokens, dtype=torch.bool)
    return {"observation": torch.rand(batch, cfg.obs_channels, cfg.obs_size, cfg.obs_size),
            "tokens": torch.randn(batch, tokens, cfg.token_dim), "positions_m": pos, "mask": mask,
            "noisy_actions": torch.randn(batch, tokens, cfg.action_dim),
            "step": torch.full((batch,), 500, dtype=torch.long), "memory": torch.randn(batch, tokens, cfg.d_model)}


def graph_modules(model) -> dict[str, tuple[nn.Module, tuple[str, ...], tuple[str, ...]]]:
    """The three networks of one robot's step: ``{role: (module, input names, output names)}``, in eval
    mode (the exporter puts a module back in the mode it found it in, children included)."""
    return {"perception": (_Perception(model).eval(), ("observation",), ("z",)),
            "encoder": (_Encoder(model).eval(), ("tokens", "positions_m", "mask"), ("memory",)),
            "denoiser": (_Denoiser(model).eval(), ("noisy_actions", "step", "memory", "positions_m", "mask"), ("eps",))}


def _axes(name: str) -> dict[int, str]:
    if name in ("observation", "z", "step"):
        return {0: "batch"}
    if name == "mask":
        return {0: "batch", 1: "tokens", 2: "tokens_kv"}
    return {0: "batch", 1: "tokens"}


def _write_graph(module: nn.Module, example: tuple[Tensor, ...], inputs: tuple[str, ...], outputs: tuple[str, ...],
                 axes: dict[str, dict[int, str]], path: Path) -> Path:
    """One ONNX graph of ``module`` at ``path``, written atomically."""
    with atomic_path(path, ".onnx", fsync=False) as tmp, torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation and tracer notes
        torch.onnx.export(module, example, str(tmp), dynamo=False, opset_version=OPSET, input_names=list(inputs),
                          output_names=list(outputs), dynamic_axes=axes)
    return path


def export_critic(net, out: Path) -> Path:
    """Write the critic ``net`` (a :class:`madp.models.critic.Critic`, eval mode) as one ONNX graph to
    ``out`` atomically: ``windows [R, 5, H, H]`` and ``neighbours [R, M, 3]`` float32
    (:func:`madp.robot.critic.critic_inputs`) -> ``mass [R]`` and ``offset [R, 2]`` (in units of
    :data:`madp.robot.critic.OFFSET_SCALE_M`), the robots axis and H dynamic, run torch-free by
    :func:`madp.robot.critic.onnx_predictor`; returns ``out``."""
    from madp.robot.critic import MAX_NEIGHBOURS

    cells = net.config.cells
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    near = torch.rand(2, MAX_NEIGHBOURS, 3).round()
    return _write_graph(net.eval(), (torch.rand(2, 5, cells, cells), near), ("windows", "neighbours"),
                        ("mass", "offset"), {"windows": {0: "robots", 2: "cells", 3: "cells"}, "neighbours": {0: "robots"}, "mass": {0: "robots"},
                                             "offset": {0: "robots"}}, out)


def export_graphs(model, out_dir: Path, learned=None) -> dict[str, Path]:
    """Write the three ONNX graphs of ``model`` (a :class:`madp.models.MADP` in eval mode) into
    ``out_dir``, each atomically, and the learned network ``learned`` a rule reads when given (a
    :class:`madp.models.map_prior.MapPrior` or a :class:`madp.models.critic.Critic`, :data:`LEARNED_GRAPHS`).
    Returns ``{role: path}``."""
    model = model.eval()
    example = _example(model)
    paths = {role: _write_graph(module, tuple(example[n] for n in inputs), inputs, outputs,
                                {n: _axes(n) for n in (*inputs, *outputs)}, out_dir / GRAPHS[role])
             for role, (module, inputs, outputs) in graph_modules(model).items()}
    from madp.models.critic import Critic

    if isinstance(learned, Critic):
        paths["critic"] = export_critic(learned, out_dir / LEARNED_GRAPHS["critic"]["critic"])
    elif learned is not None:
        side = model.config.obs_size // 2  # any window side: H and W are dynamic
        paths["map_prior"] = _write_graph(learned.eval(), (torch.rand(2, 3, side, side),), ("windows",), ("density",),
                                          {"windows": {0: "robots", 2: "rows", 3: "cols"},
                                           "density": {0: "robots", 1: "rows", 2: "cols"}},
                                          out_dir / PRIOR_GRAPH["map_prior"])
    return paths


def runtime_spec(model, meta: dict, sha256: str, sampling: SamplingSettings, params: SimParams,
                 learned: str = "") -> dict:
    """``runtime.json``: what the robot's loop needs besides the graphs.

    ``sampler``: DPM-Solver++(2M) over S steps as per-step constants: the model is evaluated at
    ``timesteps[i]`` and ``x0 = (x - sigma * eps) / alpha``, ``x <- ca * x + cb * x0 + cc * x0_prev``
    with ``(alpha, sigma, ca, cb, cc) = coefficients[i]`` (:class:`madp.models.samplers.DPMSolverMultistepSampler`);
    ``action_stats``: actions in m/s are ``x * std + mean``; ``radii``: r_c of the attention mask (and so
    of the messages a robot listens to) and the world's side (the d4 frame's centre); ``selection``:
    the frame (``d4``: element :func:`madp.robot.frame.frame_element` of the episode's seed and the
    step) and the rule keeping one of K samples per robot (:mod:`madp.policies.select`);
    ``motion``: the simulator constants the rule moves candidates with; ``source``: the checkpoint.
    ``learned``: the export holds the graph of this learned network (a key of :data:`LEARNED_GRAPHS`;
    ``graphs`` names it)."""
    cfg = model.config
    solver = model.make_sampler(sampling.sampler, sampling.sampling_steps, sampling.eta)
    return {
        "format": FORMAT, "kind": "madp", "opset": OPSET, "graphs": {**GRAPHS, **LEARNED_GRAPHS.get(learned, {})},
        "model": {"obs_channels": cfg.obs_channels, "obs_size": cfg.obs_size, "z_dim": cfg.z_dim,
                  "token_dim": cfg.token_dim, "d_model": cfg.d_model, "action_dim": cfg.action_dim,
                  "pos_token": cfg.pos_token, "num_train_steps": cfg.num_train_steps},
        "sampler": {"name": sampling.sampler, "steps": sampling.sampling_steps, "timesteps": list(solver.timesteps),
                    "coefficients": [list(c) for c in solver._coef],
                    "coefficients_are": ["alpha", "sigma", "ca", "cb", "cc"]},
        "action_stats": {"mean": [float(v) for v in model.action_mean], "std": [float(v) for v in model.action_std]},
        "radii": {"comm_radius_m": float(cfg.comm_radius_m), "world_size_m": float(cfg.world_size)},
        "selection": {"frame": sampling.frame, "rule": sampling.select, "candidates": sampling.candidates,
                      "grid_m": GRID_M},
        "motion": {"max_speed_mps": params.max_speed_mps, "dt_s": params.dt_s, "world_size": params.world_size,
                   "comm_radius_m": params.comm_radius_m, "local_map_size": params.local_map_size},
        "source": {"sha256": sha256, "step": meta.get("step"), "code_version": meta.get("code_version")},
    }


def export_policy(policy: str | Path, out_dir: str | Path, sampling: SamplingSettings | None = None,
                  params: SimParams | None = None, overwrite: bool = False) -> dict:
    """Export the MADP checkpoint ``policy`` to ``out_dir`` (created): the three graphs and
    ``runtime.json`` (module docstring). ``sampling``: the loop the JSON describes (default: the
    evaluation default, ``SamplingSettings()``); ``params``: the
    simulator constants of its motion (default :class:`SimParams`). Returns the JSON written.

    The directory is locked while it is written. A directory holding any file an export does not write
    is refused (naming the file); one holding an earlier export is replaced only with ``overwrite``.
    Its ``runtime.json`` is removed first and written last, with the sha256 of each graph, so an
    interrupted export never leaves graphs the runtime would load (it checks them).

    One-line errors for a file that is not a MADP checkpoint, for one with non-finite weights and for
    settings the runtime does not run (a sampler other than DPM-Solver++, ``fixed_noise``, the
    ``oracle`` rules that read the world), and for a rule that reads a learned network (a map prior or a
    critic, :attr:`madp.selection.Rule.needs`) with a policy file that carries none, unless the rule has a
    fallback, which the JSON then names (the default ``critic`` on a file without one: ``explore``); that
    network's graph is exported too."""
    sampling = sampling or SamplingSettings()
    if sampling.sampler != "dpm++":
        raise SettingError("sampler", f"the robot runtime runs DPM-Solver++(2M) (dpm++), got {sampling.sampler}")
    if sampling.fixed_noise:
        raise SettingError("fixed_noise", "the robot runtime draws fresh noise every step")
    if RULES[sampling.select].bound:
        raise SettingError("select", f"{sampling.select} reads the whole world: not a rule a robot can run")
    policy = Path(policy)
    sampling = sampling.fitted(carried(policy))  # a rule whose network the file lacks: its fallback, if any
    rule = RULES[sampling.select]
    model, meta = load_policy(policy)
    learned = load_learned(policy, rule.needs) if rule.needs else None
    if rule.needs and learned is None:
        raise InputError(f"{policy}: carries no {rule.needs}, which {sampling.select} ranks candidates with "
                         f"({NEEDS[rule.needs].made_by} adds one)")
    if meta["kind"] != "madp":
        raise InputError(f"{policy}: is a {meta['kind']} checkpoint; madp export writes MADP's graphs "
                         "(docs/guides/export.md: LPAC-K3)")
    check_sampling_steps(model, sampling.sampling_steps)
    bad = [name for name, t in (*model.named_parameters(), *model.named_buffers())
           if t.is_floating_point() and not bool(torch.isfinite(t).all())]
    if bad:
        raise InputError(f"{policy}: non-finite weights (NaN or inf) in {bad[0]}"
                         f"{f' and {len(bad) - 1} more' if len(bad) > 1 else ''}; a robot would command NaN")
    out = Path(out_dir)
    with locked_dir(out):
        owned = [*GRAPHS.values(), *(name for g in LEARNED_GRAPHS.values() for name in g.values()), RUNTIME_JSON]
        foreign = foreign_files(out, owned)
        if foreign:
            raise InputError(f"{foreign[0]}: not a file madp export writes; export into an empty --out directory")
        if any((out / name).exists() for name in owned) and not overwrite:
            raise InputError(f"{out}: already holds an export; pass --overwrite to replace it")
        (out / RUNTIME_JSON).unlink(missing_ok=True)  # no loadable export until every graph is written
        for graph in LEARNED_GRAPHS.values():  # an earlier export's prior or critic, if any
            for name in graph.values():
                (out / name).unlink(missing_ok=True)
        paths = export_graphs(model, out, learned)
        spec = write_runtime(out, runtime_spec(model, meta, sha256_file(policy), sampling, params or SimParams(),
                                               learned=rule.needs), paths)
    return spec


def write_runtime(out: Path, spec: dict, paths: dict[str, Path]) -> dict:
    """Write ``runtime.json`` into ``out`` (atomically, after the graphs): ``spec`` with the sha256 of
    each graph of ``paths`` (``{role: path}``, :func:`export_graphs`), which the runtime checks at load."""
    spec = {**spec, "graph_sha256": {role: sha256_file(path) for role, path in paths.items()}}
    write_json_atomic(Path(out) / RUNTIME_JSON, spec)
    return spec

