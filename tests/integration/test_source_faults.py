"""End to end: ``zenslam run`` with ``source.faults`` on a short synthetic run: dropped frames and repeated stamps
are skipped, counted in metrics.json and never waited for, and tracking goes on across the gaps."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from zenslam.service.evaluation.trajectory_io import read_tum

pytestmark = pytest.mark.integration

FRAMES = 40
ATE_BOUND_M = 0.02  # as test_run_synthetic: the loop tracks to a few mm over its first frames


@pytest.mark.slow(12)
def test_dropped_frames_and_repeated_stamps_are_skipped_and_counted(tmp_path: Path):
    config = tmp_path / "faults.yaml"
    config.write_text(
        "source:\n"
        "  faults:\n"
        "    - {kind: drop, first_frame: 10, last_frame: 12}\n"
        "    - {kind: stamp_repeat, first_frame: 20, last_frame: 21}\n"
    )
    command = [sys.executable, "-m", "zenslam.service.cli", "run", "synthetic", "--config", str(config),
               "--max-frames", str(FRAMES), "--output", str(tmp_path), "--run-id", "it-faults", "--no-progress"]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    assert "frames skipped by the source: 5 (3 drop, 2 stamp_repeat)" in result.stdout
    run_dir = tmp_path / "it-faults"
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["skipped_frames"] == {"total": 5, "reasons": {"drop": 3, "stamp_repeat": 2}}
    # --max-frames counts the frames sent: 40 of the first 45, all tracked.
    assert metrics["run"]["completed"] is True
    assert metrics["frames"] == FRAMES and metrics["lost_frames"] == 0
    assert metrics["ate"]["rmse_m"] < ATE_BOUND_M
    trajectory = read_tum(run_dir / "trajectory.tum")
    assert len(trajectory) == FRAMES
    assert (trajectory.stamps_ns[1:] > trajectory.stamps_ns[:-1]).all()
    source_log = (run_dir / "logs" / "source.log").read_text()
    warnings = [line for line in source_log.splitlines() if "skipping frame" in line]
    assert [w.split("skipping frame ")[1].split(":")[0] for w in warnings] == ["10", "11", "12", "20", "21"]
    assert "repeats the stamp of frame 19" in warnings[3]
