"""``madp swarm``: one robot process per robot over Zenoh, driven by the world process (:mod:`madp.swarm`)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from madp.sampling import sampling_help

__all__ = ["swarm_cmd"]


def swarm_cmd(
    scenario: Path = typer.Option(..., "--scenario", help="Scenario JSON (features, robots, optional params)."),
    policy: Path = typer.Option(..., "--policy", help="The directory madp export wrote (runtime.json and the ONNX graphs)."),
    steps: int = typer.Option(600, min=1, help="Control steps to run."),
    out: Path = typer.Option(..., help="Output directory: summary.json and swarm.mcap (a rosbag2 log)."),
    network: Optional[str] = typer.Option(None, help="The radio between the robots: a group of the faults suite (ideal, loss_30, delay_1s, fail_25, noise_5m, ...) or NAME=VALUE items as madp rollout --network (default: ideal)."),
    rate_hz: Optional[float] = typer.Option(None, "--rate-hz", help="Run in real time at this rate (Hz): each phase of a step has a deadline (beacons by 25 %, tokens by 60 %, the _joint rules' costs by 90 %, commands by 100 % of the period) and what misses it is lost (default: lockstep, every phase waits for every robot)."),
    sampling: Optional[str] = typer.Option(None, "--sampling", help=sampling_help("The export fixes sampler, steps and precision; its rule, k and frame may change here, for every robot process.")),
    overwrite: bool = typer.Option(False, help="Replace an earlier madp swarm run in --out (the files its record madp-swarm.json lists: summary.json, swarm.mcap); any other file makes it refuse, naming the file."),
) -> None:
    """Run a swarm as one process per robot (the exported policy, torch-free) over Zenoh; the world
    process simulates physics, sensors and the radio. Writes OUT/summary.json and OUT/swarm.mcap."""
    from madp.commands.rollout import network_settings
    from madp.swarm import run_swarm

    net = network_settings(network) if network is not None else None
    s = run_swarm(scenario, policy, steps, out, net, rate_hz, overwrite, sampling=sampling)
    failed = ", ".join(f"robot {f['robot']} at step {f['step']}" for f in s["failed"]) or "none"
    lat = s["latency_ms"]
    ms = "n/a" if lat["p50"] is None else f"p50 {lat['p50']:.1f} ms, p99 {lat['p99']:.1f} ms"
    typer.echo(f"swarm of {s['robots_n']} robot processes ({s['mode']}): J({steps})/J(0) = {s['final_cost']:.4f}; "
               f"step latency {ms}; deadline misses {s['deadline_misses']}; failed: {failed} -> {out}")
