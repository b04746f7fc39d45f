"""A monocular run end to end: the two-view start over the bus, Sim(3) scoring, an identical lockstep replay."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.integration

FRAMES = 20  # the loop scene starts its monocular map at about frame 7


@pytest.mark.slow(60)
def test_monocular_run_starts_a_map_scores_with_sim3_and_replays_identically(tmp_path):
    def zenslam(*args: str) -> subprocess.CompletedProcess:
        command = [sys.executable, "-m", "zenslam.service.cli", *args, "--output", str(tmp_path), "--no-progress"]
        result = subprocess.run(command, capture_output=True, text=True, timeout=900)
        assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
        return result

    zenslam("run", "synthetic:loop", "--sensor", "mono", "--max-frames", str(FRAMES), "--run-id", "mono")
    metrics = json.loads((tmp_path / "mono" / "metrics.json").read_text())
    assert metrics["frames"] == FRAMES and 0 < metrics["initializing_frames"] <= 10
    assert metrics["tracked_ok"] == FRAMES - metrics["initializing_frames"]
    assert metrics["initializing_reasons"]["waiting_for_second_frame"] == 1
    assert metrics["keyframes"]["sent"] == metrics["keyframes"]["processed"] >= 3
    assert metrics["ate"]["alignment"] == "sim3" and metrics["ate"]["scale"] > 0
    replayed = zenslam("replay", str(tmp_path / "mono" / "run.mcap"), "--run-id", "mono-replay")
    assert "identical" in replayed.stdout.splitlines(), replayed.stdout[-3000:]
