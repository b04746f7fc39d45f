"""End to end: the real source and frontend processes over zenoh on loopback, on a short synthetic sequence.

The first tests follow the run the way the ``zenslam run`` process does (it is a bus consumer) and
check the states and poses that arrive; then the command itself: what it prints and writes, and that
lockstep runs repeat exactly. Both runs are the shared ones of conftest.py.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from zenslam.service.evaluation.metrics import evaluate
from zenslam.service.recorder_config import RecorderConfig
from zenslam.service.sources import open_source

pytestmark = pytest.mark.integration

FRAMES = 30  # of each run, the shared ones and the pipelined one

ATE_BOUND_M = 0.02  # the synthetic loop tracks to ~3 mm over its first 30 frames (0.5 m of path)


def _poses(path: Path) -> list[str]:
    """The pose lines of a TUM file (comments dropped)."""
    return [line for line in path.read_text().splitlines() if line and not line.startswith("#")]


@pytest.fixture(scope="module")
def lockstep_run(tracked_run) -> tuple[Path, object, object]:
    assert tracked_run.frames == FRAMES
    return tracked_run.run_dir, tracked_run.log, tracked_run.result


def test_every_frame_is_tracked_and_its_pose_arrives(lockstep_run):
    _, log, _ = lockstep_run
    assert log.ended
    assert sorted(log.states) == list(range(FRAMES))
    assert [log.states[i].state for i in range(FRAMES)] == ["ok"] * FRAMES
    assert all(log.states[i].n_tracked >= 50 for i in range(FRAMES))
    assert log.missing_poses() == 0 and len(log.poses) == FRAMES
    assert log.states[0].keyframe_id == 0  # the map starts with a keyframe
    for T in log.poses.values():
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)


def test_the_arrived_poses_match_the_ground_truth(lockstep_run):
    _, log, _ = lockstep_run
    evaluation = evaluate(log.trajectory(), open_source("synthetic").ground_truth())
    assert evaluation.ate.matched_poses == FRAMES
    assert evaluation.ate.rmse_m < ATE_BOUND_M


def test_the_run_folder(lockstep_run):
    run_dir, _, result = lockstep_run
    names = {p.name for p in run_dir.iterdir()}
    assert {"config.yaml", "trajectory.tum", "keyframes.tum", "metrics.json", "trajectory_top.png", "logs"} <= names
    assert {"frontend.log", "source.log"} <= {p.name for p in (run_dir / "logs").iterdir()}
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["frames"] == FRAMES and metrics["lost_frames"] == 0
    assert metrics["ate"]["rmse_m"] == pytest.approx(result.evaluation.ate.rmse_m)
    assert {"extraction", "stereo_matching", "pose_optimization", "total"} <= set(metrics["timing"])
    assert len(_poses(run_dir / "trajectory.tum")) == FRAMES


def test_the_command_prints_the_ate_and_repeats_exactly(lockstep_run, command_run):
    run_dir, _, _ = lockstep_run
    assert "ATE RMSE" in command_run.stdout
    metrics = json.loads((command_run.run_dir / "metrics.json").read_text())
    assert metrics["frames"] == command_run.frames == FRAMES and metrics["ate"]["rmse_m"] < ATE_BOUND_M
    # Lockstep runs are deterministic: the command and the run followed in this process give the same bytes.
    assert _poses(command_run.run_dir / "trajectory.tum") == _poses(run_dir / "trajectory.tum")


def _niceness(run_dir: Path, stage: str) -> list[int]:
    """The niceness a stage logged it runs at (ours plus its increment), once, or nothing."""
    return [int(n) for n in re.findall(r"niceness (-?\d+): ", (run_dir / "logs" / f"{stage}.log").read_text())]


def test_lockstep_stages_keep_their_priority(command_run):
    # Lockstep tracking waits for each keyframe's mapping, and for the recording: no one yields.
    assert all(_niceness(command_run.run_dir, stage) == [] for stage in ("frontend", "backend", "recorder"))


@pytest.mark.slow(12)
def test_a_pipelined_run_tracks_every_frame_and_waits_for_every_keyframe(tmp_path):
    """``--pipelined``: lockstep frames, map updates applied as they arrive; nothing dropped, nothing left unmapped."""
    command = [sys.executable, "-m", "zenslam.service.cli", "run", "synthetic", "--pipelined", "--max-frames", str(FRAMES),
               "--output", str(tmp_path), "--run-id", "it-pipelined", "--no-progress"]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    run_dir = tmp_path / "it-pipelined"
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["run"]["mode"] == "pipelined" and metrics["run"]["completed"] is True
    assert metrics["frames"] == FRAMES and metrics["lost_frames"] == 0
    assert metrics["keyframes"]["sent"] >= 2 and metrics["keyframes"]["processed"] == metrics["keyframes"]["sent"]
    assert len(_poses(run_dir / "trajectory.tum")) == FRAMES
    assert len(_poses(run_dir / "keyframes.tum")) >= 2
    # Which frames become keyframes depends on timing here, not the accuracy: same bound as lockstep.
    assert metrics["ate"]["rmse_m"] < ATE_BOUND_M
    assert "mode: pipelined" in (run_dir / "config.yaml").read_text()
    # Recording runs beside tracking and yields the CPU to it; mapping, whose keyframes tracking
    # holds back when it falls behind, keeps its priority (the backend yields in live runs only).
    assert _niceness(run_dir, "recorder") == [min(os.nice(0) + RecorderConfig().nice, 19)]
    assert _niceness(run_dir, "backend") == [] and _niceness(run_dir, "frontend") == []
