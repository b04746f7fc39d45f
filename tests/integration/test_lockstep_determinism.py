"""Lockstep runs of source, frontend and backend are deterministic: the same input gives the same bytes out.

Two ``zenslam run --lockstep`` commands on the same short synthetic sequence, in separate
process trees, must write byte-identical trajectory.tum (every frame, tracked against a map the
backend corrected after each keyframe) and keyframes.tum (the backend's final keyframe poses).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

FRAMES = 24


def _run(output: Path, run_id: str) -> Path:
    command = [sys.executable, "-m", "zenslam.service.cli", "run", "synthetic", "--lockstep", "--max-frames", str(FRAMES),
               "--output", str(output), "--run-id", run_id, "--no-progress"]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    return output / run_id


def test_two_lockstep_runs_write_identical_trajectories(tmp_path):
    first, second = _run(tmp_path, "first"), _run(tmp_path, "second")
    for name in ("trajectory.tum", "keyframes.tum"):
        a, b = (first / name).read_bytes(), (second / name).read_bytes()
        assert a == b, f"{name} differs between two lockstep runs"
    metrics = json.loads((first / "metrics.json").read_text())
    assert metrics["frames"] == FRAMES and metrics["keyframes_from"] == "backend"
    assert metrics["keyframes"]["sent"] == metrics["keyframes"]["processed"] >= 3
    assert len((first / "keyframes.tum").read_text().splitlines()) >= 1 + 3  # header + keyframes kept
    assert {"local_ba", "triangulation", "total"} <= set(metrics["backend_timing"])
