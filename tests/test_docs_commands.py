"""The user guide's shell blocks (docs/*.md), each run as written from a scratch checkout.

Blocks a user runs in two terminals (a publisher and a run) start the first line in the background.
The two-machine block runs on loopback: its router is a zenoh session in router mode in this process
(zenohd is not on PyPI), and the server's and robot's configs are the guide's with that router's
port. ``ros2 topic echo`` needs a ROS 2 installation and is skipped without one. The blocks that
meet on zenoh's default port 7447, as the guide's do, share one xdist group so that they never run
at the same time.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
from pathlib import Path

import pytest
import zenoh
import yaml
from test_docs import command_env, command_lines, doc_block, run_line, scratch_checkout

from zenslam.runtime import bus
from zenslam.service.run_config import load_run_config

DEFAULT_PORT_GROUP = "zenoh-port-7447"  # the blocks whose processes meet on tcp/127.0.0.1:7447
_EXIT_TIMEOUT_S = 600.0  # generous: a loaded 2-core machine runs these clips in well under a minute


def _start_line(line: str, cwd: Path, log_name: str) -> subprocess.Popen:
    """A documented command started in the background (its own terminal, for a user), logging to ``cwd``."""
    log = open(cwd / f"{log_name}.log", "wb")  # noqa: SIM115 - closed with the process by _finish
    return subprocess.Popen(["bash", "-c", f"exec {line}"], cwd=cwd, stdout=log, stderr=subprocess.STDOUT,
                            env=command_env(), process_group=0)  # fmt: skip


def _finish(process: subprocess.Popen, cwd: Path, log_name: str, timeout_s: float = _EXIT_TIMEOUT_S) -> str:
    """Wait for a background command to exit with status 0; its log."""
    try:
        status = process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
        status = None
    log = (cwd / f"{log_name}.log").read_text(errors="replace")
    assert status == 0, f"{log_name} ended with {status}:\n{log[-3000:]}"
    return log


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def _metrics(checkout: Path, run_id: str) -> dict:
    return json.loads((checkout / "recordings" / run_id / "metrics.json").read_text())


@pytest.mark.extended  # runs zenslam: CI runs it after the README's command
def test_sources_commands_run_in_order(tmp_path: Path):
    checkout = scratch_checkout(tmp_path)
    outputs = [run_line(line, checkout).stdout for line in command_lines("sources")]
    assert re.search(r"^frames: +901$", outputs[0], re.M), outputs[0]
    assert (checkout / "recordings" / "scenes" / "figure_eight_tum" / "rgb.txt").is_file()
    assert re.search(r"^sensor: +rgbd$", outputs[2], re.M) and re.search(r"^frames: +10$", outputs[2], re.M), outputs[2]


def test_the_documented_run_yaml_is_a_valid_config(tmp_path: Path):
    path = tmp_path / "run.yaml"
    path.write_text(doc_block("yaml", "run.yaml") + "\n")
    config = load_run_config(path)
    assert config.mode == "lockstep" and config.source.spec == "synthetic:loop" and config.source.max_frames == 30
    assert not config.rerun.enabled


@pytest.mark.extended  # a 30-frame run: CI runs it after the README's command
@pytest.mark.slow(15)
def test_config_commands_run_the_documented_yaml(tmp_path: Path):
    checkout = scratch_checkout(tmp_path)
    (checkout / "run.yaml").write_text(doc_block("yaml", "run.yaml") + "\n")
    help_line, run = command_lines("config")
    help_text = " ".join(run_line(help_line, checkout).stdout.split())
    for section in ("bus", "source", "frontend", "backend", "rerun", "evaluation", "recorder", "supervision"):
        assert section in help_text
    assert "ATE RMSE" in run_line(run, checkout).stdout
    written = yaml.safe_load((checkout / "recordings" / "configured" / "config.yaml").read_text())
    assert written["source"]["spec"] == "synthetic:loop" and written["frontend"]["orb"]["n_features"] == 1200
    assert _metrics(checkout, "configured")["frames"] == 30
    assert not list((checkout / "recordings" / "configured").glob("*.rrd"))  # rerun.enabled: false


@pytest.mark.extended  # three 40-frame runs: CI runs it after the README's command
@pytest.mark.slow(40)
def test_modes_commands_run_in_order(tmp_path: Path):
    checkout = scratch_checkout(tmp_path)
    for line in command_lines("modes"):
        assert "ATE RMSE" in run_line(line, checkout).stdout
    for run_id, mode in (("lockstep40", "lockstep"), ("pipelined40", "pipelined"), ("live40", "live")):
        metrics = _metrics(checkout, run_id)
        assert metrics["run"]["mode"] == mode and metrics["run"]["completed"], metrics["run"]
        if mode == "live":  # a slow stage skips frames, as the guide says
            assert 0 < metrics["frames"] <= 40
        else:
            assert metrics["frames"] == 40


def _run_pair(block: str, checkout: Path) -> tuple[str, str]:
    """A block of two lines a user runs in two terminals: the publisher's log, the run's output."""
    publish, run = command_lines(block)
    publisher = _start_line(publish, checkout, "publisher")
    try:
        result = run_line(run, checkout)
        return _finish(publisher, checkout, "publisher"), result.stdout + result.stderr
    finally:
        _stop(publisher)


@pytest.mark.extended  # the KITTI clip published at its rate and tracked: CI runs it after the README's command
@pytest.mark.slow(40)
@pytest.mark.xdist_group(DEFAULT_PORT_GROUP)
def test_zenoh_pair_tracks_the_published_clip(tmp_path: Path, data_root: Path, kitti_root: Path):
    checkout = scratch_checkout(tmp_path, data_root)
    publisher_log, run_output = _run_pair("zenoh-pair", checkout)
    assert "ATE RMSE" in run_output, run_output[-2000:]
    (run_folder,) = (checkout / "recordings").iterdir()
    metrics = json.loads((run_folder / "metrics.json").read_text())
    assert metrics["frames"] + metrics["dropped_frames"]["total"] >= 45, metrics  # live: a busy tracker skips some


@pytest.mark.extended  # a 40-frame scene over the ROS 2 keys: CI runs it after the README's command
@pytest.mark.slow(30)
@pytest.mark.xdist_group(DEFAULT_PORT_GROUP)
def test_ros2_pair_tracks_the_published_scene(tmp_path: Path):
    checkout = scratch_checkout(tmp_path)
    publisher_log, run_output = _run_pair("ros2-pair", checkout)
    assert "published 40 frames" in publisher_log, publisher_log[-2000:]
    assert "ATE RMSE" in run_output, run_output[-2000:]
    assert re.search(r"published \d+ poses and \d+ paths on ROS 2 domain 0", run_output), run_output[-2000:]


@pytest.mark.extended
@pytest.mark.xdist_group(DEFAULT_PORT_GROUP)
@pytest.mark.skipif(shutil.which("ros2") is None or shutil.which("timeout") is None,
                    reason="ROS 2 is not installed: `ros2 topic echo` cannot run here (the zenslam side of the "
                    "guide's ROS 2 commands is run by test_ros2_pair_tracks_the_published_scene)")  # fmt: skip
def test_ros2_echo_sees_the_published_poses(tmp_path: Path):
    """With ROS 2 on rmw_zenoh: its router, a run publishing to ROS 2, and the guide's ``ros2 topic echo``."""
    checkout = scratch_checkout(tmp_path)
    (echo,) = command_lines("ros2-echo")
    env = {**command_env(), **{k: v for k, v in os.environ.items() if k.startswith(("ROS_", "AMENT_", "LD_LIBRARY"))},
           "RMW_IMPLEMENTATION": "rmw_zenoh_cpp"}  # fmt: skip
    router = subprocess.Popen(["ros2", "run", "rmw_zenoh_cpp", "rmw_zenohd"], cwd=checkout, env=env, process_group=0)
    try:
        listener = subprocess.Popen(["bash", "-c", f"timeout 300 {echo} --once"], cwd=checkout, env=env,
                                    stdout=subprocess.PIPE, text=True, process_group=0)  # fmt: skip
        run_line("zenslam run synthetic --max-frames 40 --ros2-publish --run-id ros2-echo", checkout)
        out, _ = listener.communicate(timeout=300)
        assert "pose:" in out and "position:" in out, out
    finally:
        _stop(router)


@pytest.mark.extended  # the KITTI clip through four stage processes and a router: CI runs it after the README's command
@pytest.mark.slow(60)
def test_machines_commands_on_loopback(tmp_path: Path, data_root: Path, kitti_root: Path):
    checkout = scratch_checkout(tmp_path, data_root)
    endpoint = bus.free_tcp_endpoint()
    router = doc_block("json5", "router.json5").replace("tcp/0.0.0.0:7447", endpoint)
    for name, address in (("server.json5", "tcp/127.0.0.1:7447"), ("robot.json5", "tcp/192.168.1.10:7447")):
        config = doc_block("json5", name)
        assert address in config
        (checkout / name).write_text(config.replace(address, endpoint))
    (checkout / "run.yaml").write_text(doc_block("yaml", "machines/run.yaml") + "\n")
    lines = command_lines("machines")
    roles = [line.split()[2] for line in lines]
    assert roles == ["backend", "recorder", "frontend", "source"]
    with zenoh.open(zenoh.Config.from_json5(router)):
        stages = {role: _start_line(line, checkout, role) for role, line in zip(roles, lines, strict=True)}
        try:
            for role in ("source", "frontend", "recorder"):
                _finish(stages[role], checkout, role)
            stages["backend"].send_signal(signal.SIGINT)  # it lingers for queries until Ctrl-C
            _finish(stages["backend"], checkout, "backend", timeout_s=120)
        finally:
            for process in stages.values():
                _stop(process)
    run_folder = checkout / "recordings" / "field1"
    assert (run_folder / "run.mcap").is_file() and (run_folder / "keyframes.tum").is_file()
    metrics = json.loads((run_folder / "metrics.json").read_text())
    assert metrics["frames"] == 51 and metrics["ate"]["rmse_m"] < 0.1, metrics
