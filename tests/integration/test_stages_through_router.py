"""Stages started one by one with ``zenslam stage``, as zenoh clients of a router, give the single-machine lockstep bytes.

The router is a zenoh session opened in router mode in this process (zenohd is not on PyPI),
listening on a free loopback port; each stage is its own ``zenslam stage ROLE`` process in client
mode (the README's two-machine configs, on one machine), started in the reverse order of
``zenslam run``'s: every stage waits for the ones it needs by their liveliness tokens. The recorder
writes the run folder from its recording; its trajectory.tum and keyframes.tum must equal those
of the ``zenslam run --lockstep`` command on the same frames and configuration (``command_run``).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from zenslam.runtime import bus
from zenslam.runtime.rerun_config import RerunConfig
from zenslam.service.run_config import RunConfig, SourceConfig, run_config_to_yaml

pytestmark = pytest.mark.integration

_EXIT_TIMEOUT_S = 300.0  # generous: a loaded 2-core machine runs the 30 frames in well under a minute


def router_config(endpoint: str) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("router"))
    config.insert_json5("listen/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    return config


def client_config_json5(endpoint: str) -> str:
    """What a machine's stages use: client mode, connected to the router only."""
    return (
        '{\n  mode: "client",\n'
        f'  connect: {{ endpoints: ["{endpoint}"] }},\n'
        "  scouting: { multicast: { enabled: false } },\n}\n"
    )


def _start(role: str, session: str, bus_config: Path, config: Path, cwd: Path) -> subprocess.Popen:
    command = [sys.executable, "-m", "zenslam.service.cli", "stage", role, "--session", session,
               "--bus-config", str(bus_config), "--config", str(config)]  # fmt: skip
    log = open(cwd / f"{role}.log", "wb")
    return subprocess.Popen(command, cwd=cwd, stdout=log, stderr=subprocess.STDOUT, process_group=0)


def _wait_exit(process: subprocess.Popen, name: str, cwd: Path, timeout_s: float) -> int:
    try:
        return process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{name} did not exit within {timeout_s:.0f} s:\n{(cwd / f'{name}.log').read_text()[-3000:]}")


@pytest.mark.slow(30)  # the four stages on 30 frames, plus the shared command run it compares with
def test_stages_through_a_router_write_the_lockstep_bytes(command_run, tmp_path: Path):
    endpoint = bus.free_tcp_endpoint()
    session = "it-router"
    bus_config = tmp_path / "client.json5"
    bus_config.write_text(client_config_json5(endpoint))
    config = tmp_path / "run.yaml"
    # command_run's configuration (its frames, lockstep); rerun off: it changes no output.
    run_config = RunConfig(source=SourceConfig(spec="synthetic", max_frames=command_run.frames), rerun=RerunConfig(enabled=False))
    config.write_text(run_config_to_yaml(run_config))
    processes: dict[str, subprocess.Popen] = {}
    with zenoh.open(router_config(endpoint)):
        try:
            for role in ("source", "frontend", "backend", "recorder"):  # the reverse of zenslam run's order
                processes[role] = _start(role, session, bus_config, config, tmp_path)
            # The recorder finishes once the source and frontend have gone and the backend has answered
            # its final trajectory query; the backend lingers for other clients' queries until stopped.
            for role in ("source", "frontend", "recorder"):
                assert _wait_exit(processes[role], role, tmp_path, _EXIT_TIMEOUT_S) == 0, (tmp_path / f"{role}.log").read_text()[-3000:]
            processes["backend"].send_signal(signal.SIGINT)
            assert _wait_exit(processes["backend"], "backend", tmp_path, 30.0) == 0
        finally:
            for process in processes.values():
                if process.poll() is None:
                    process.kill()
                    process.wait()
    run_dir = tmp_path / "recordings" / session
    for name in ("trajectory.tum", "keyframes.tum"):
        assert (run_dir / name).read_bytes() == (command_run.run_dir / name).read_bytes(), name
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["run"]["completed"] is True and metrics["keyframes_from"] == "backend"
    assert metrics["frames"] == command_run.frames and "ate" in metrics  # the source's ground truth was recorded
    assert (run_dir / "run.mcap").is_file()
