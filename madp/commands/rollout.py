"""``madp rollout``'s work (:mod:`madp.cli` parses its options): one controller on one scenario, with
``--runtime onnx`` decentralized MADP robot by robot through the exported graphs, each robot's
starting noise its own (:class:`madp.export.swarm.OnnxMADPPolicy` with ``noise="robot"``, what a robot
process draws: the one-process reference of a swarm of robot processes)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import typer

from madp.errors import SettingError
from madp.io.atomic import write_json_atomic


def network_settings(text: str):
    """``--network``: a faults-suite group's network, or NAME=VALUE items (:meth:`NetworkSettings.parse`)."""
    from madp.eval.suites import FAULTS
    from madp.sim.network import NetworkSettings

    if text in FAULTS:
        return FAULTS[text]
    if "=" not in text:
        raise SettingError("network", f"expected a group of the faults suite ({', '.join(FAULTS)}) or NAME=VALUE "
                                      f"items, got {text!r}")
    return NetworkSettings.parse(text)


def check_runtime(runtime: str, controller: str) -> None:
    """Refuse, before anything is read or run, a ``--runtime`` that is not one of :data:`RUNTIMES`,
    ``onnx`` for a controller other than decentralized MADP, or ``onnx`` without madp's ``onnx`` extra."""
    from madp.controllers import controller_info
    from madp.errors import check_extra
    from madp.sampling import ONNX_MODULES
    from madp.sampling import RUNTIMES

    if runtime not in RUNTIMES:
        raise SettingError("runtime", f"expected one of {', '.join(RUNTIMES)}, got {runtime!r}")
    if runtime == "onnx":
        info = controller_info(controller)
        if not info.samples or info.mode != "decentralized":
            raise SettingError("runtime", f"onnx runs MADP robot by robot (decentralized), not {controller}")
        check_extra("runtime", "onnx", "onnx", ONNX_MODULES)


def check_record(record_format: str) -> None:
    """Refuse, before anything runs, a ``--record-format`` that is not one of
    :data:`madp.recordings.recorders.RECORD_FORMATS`, or ``ros2`` without madp's ``ros2`` extra."""
    from madp.recordings.recorders import RECORD_FORMATS
    from madp.errors import check_extra

    if record_format not in RECORD_FORMATS:
        raise SettingError("record_format", f"expected one of {', '.join(RECORD_FORMATS)}, got {record_format!r}")
    if record_format == "ros2":
        check_extra("record_format", "ros2", "ros2", ("mcap_ros2",))


def check_outputs(out: Path, record: Path | None) -> None:
    """Refuse, before anything runs, an ``--out`` or ``--record`` that cannot take a new file (a
    directory; a directory that cannot be made or written in), and ``--record`` equal to ``--out`` (the
    recording would replace the result). Makes their directories; the errors name the user's paths."""
    if record is not None and Path(os.path.abspath(record)).resolve() == Path(os.path.abspath(out)).resolve():
        raise SettingError("record", f"{record} is also --out: the recording would replace the result JSON; "
                                     "choose another path")
    for setting, path in (("out", out), ("record", record)):
        if path is None:
            continue
        path = Path(path)
        if path.is_dir() or str(path).endswith(os.sep):
            raise SettingError(setting, f"{path} is a directory; expected a file name")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=path.parent):
                pass
        except OSError as e:
            raise SettingError(setting, f"{path}: cannot write a file in {path.parent} "
                                        f"({e.strerror or type(e).__name__})") from None


def run_rollout(scenario: Path, controller: str, checkpoint: Path | None, seed: int | None, steps: int, out: Path,
                video: Path | None, device: str, sampling_spec: str | None, select: str | None, candidates: int | None,
                network: str | None, record: Path | None, record_format: str, runtime: str) -> None:
    """``madp rollout`` with its options' values: write the result JSON (and the recording, the video)
    and print a line for each."""
    from madp.controllers import controller_info, make_controller, resolve_checkpoint
    from madp.recordings.recorders import recorder
    from madp.policies import SamplingSettings
    from madp.policies.device import resolve_device
    from madp.sampling import merge_sampling, spec_text
    from madp.sim import CoverageEnv, Scenario, rollout as run
    from madp.video import Frames, check_video_path

    learned = controller_info(controller).learned  # an unknown name is refused before anything is read
    if checkpoint is not None and not learned:
        raise SettingError("checkpoint", f"the {controller} controller takes no checkpoint")
    check_runtime(runtime, controller)
    device = resolve_device(device)  # checked, like the video path, before anything is read or run
    given = merge_sampling(sampling_spec, select=select, candidates=candidates)
    if given and not controller_info(controller).samples:
        raise SettingError("sampling" if sampling_spec else "select", f"the {controller} controller does not sample")
    sampling = SamplingSettings.of(**given) if learned else None  # MADP's; checked
    frames = [Frames(check_video_path(video), steps)] if video is not None else []
    check_record(record_format)  # the format, its extra and the paths are checked before anything runs
    check_outputs(out, record)
    net = network_settings(network) if network is not None else None
    sc = Scenario.load(scenario)
    seed = seed if seed is not None else sc.seed or 0
    if runtime == "onnx":
        from madp.export.swarm import OnnxMADPPolicy

        ctrl = OnnxMADPPolicy(resolve_checkpoint(controller, checkpoint and str(checkpoint)), sampling, seed=seed,
                              noise="robot")
    else:
        ctrl = make_controller(controller, checkpoint and str(checkpoint), seed=seed, sampling=sampling, device=device)
    env = CoverageEnv(sc, network=net)
    rec = recorder(record_format, env, ctrl, controller, steps) if record is not None else None
    result = run(env, ctrl, steps, frames + ([rec] if rec else []))
    doc = result.to_json(controller)
    if controller_info(controller).samples:  # how it sampled, and where its starting noise came from
        sampling = ctrl.sampling  # as it ran: the rule's fallback on a file without the network it reads
        doc["sampling"] = {"spec": spec_text(sampling.as_dict()), **sampling.as_dict(), "runtime": runtime,
                           "noise": "robot" if runtime == "onnx" else "torch"}
    if env.network is not None:  # the network's settings and the bytes each robot put on the air per step
        doc["network"] = {"settings": net.as_dict(), "bytes_per_robot_step": env.network.bytes_per_robot_step(steps)}
    write_json_atomic(out, doc)
    if rec is not None:
        typer.echo(f"{record_format} recording: {rec.write(record)}")
    typer.echo(f"{controller}: J({steps})/J(0) = {result.normalized_cost[-1]:.4f}"
               f" (converged at {result.converged_at}) -> {out}")
    for f in frames:
        v = f.write(progress=True)
        typer.echo(f"video: {v['frames']} frames, {v['width']}x{v['height']}, {v['bytes'] / 1e6:.1f} MB -> {video}")
