"""Lockstep runs of source, frontend and backend are deterministic: the same input gives the same bytes out.

Two lockstep runs of the same short synthetic sequence, in separate process trees (the
``zenslam run --lockstep`` command, and the same run followed by this process; both shared with other
modules by conftest.py), must write byte-identical trajectory.tum (every frame, tracked against a
map the backend corrected after each keyframe) and keyframes.tum (the backend's final keyframe poses).
"""

from __future__ import annotations

import json

import pytest

pytestmark = pytest.mark.integration


@pytest.mark.slow(25)  # with the two shared runs it compares
def test_two_lockstep_runs_write_identical_trajectories(command_run, tracked_run):
    first, second = command_run.run_dir, tracked_run.run_dir
    for name in ("trajectory.tum", "keyframes.tum"):
        a, b = (first / name).read_bytes(), (second / name).read_bytes()
        assert a == b, f"{name} differs between two lockstep runs"
    metrics = json.loads((first / "metrics.json").read_text())
    assert metrics["frames"] == command_run.frames and metrics["keyframes_from"] == "backend"
    assert metrics["keyframes"]["sent"] == metrics["keyframes"]["processed"] >= 3
    assert len((first / "keyframes.tum").read_text().splitlines()) >= 1 + 3  # header + keyframes kept
    assert {"local_ba", "triangulation", "total"} <= set(metrics["backend_timing"])


@pytest.mark.extended  # CI runs it after the README's command
@pytest.mark.slow(40)
def test_a_lockstep_run_with_tracking_beside_local_mapping_replays_identically(tmp_path):
    """``frontend.lockstep_lag_frames``: keyframe answers applied frames later, at frames fixed by
    the stream, so a recording of such a run replays bit for bit through the whole pipeline."""
    import subprocess
    import sys

    config = tmp_path / "lag.yaml"
    config.write_text("frontend:\n  lockstep_lag_frames: 3\nrerun:\n  enabled: false\n")
    run = [sys.executable, "-m", "zenslam.service.cli", "run", "synthetic", "--lockstep", "--max-frames", "30",
           "--config", str(config), "--output", str(tmp_path), "--run-id", "lag", "--no-progress"]  # fmt: skip
    result = subprocess.run(run, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    assert "lockstep_lag_frames: 3" in (tmp_path / "lag" / "config.yaml").read_text()
    replay = [sys.executable, "-m", "zenslam.service.cli", "replay", str(tmp_path / "lag" / "run.mcap"),
              "--output", str(tmp_path), "--run-id", "again", "--no-progress"]  # fmt: skip
    result = subprocess.run(replay, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert result.returncode == 0 and "identical" in result.stdout.splitlines(), result.stdout[-2000:] + result.stderr[-3000:]
