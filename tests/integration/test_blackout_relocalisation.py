"""End to end: ``zenslam run`` on the synthetic loop with the camera blacked out for longer than
``tracking.reinit_after_lost_frames``: the frontend relocalises on the old map as soon as the images
return, through the backend's keyframe database, and starts no new map."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from zenslam.service.evaluation.trajectory_io import read_tum
from zenslam.service.sources.synthetic import scene_config

pytestmark = pytest.mark.integration

FRAMES = 80
BLACK = (30, 45)  # 16 black frames, more than reinit_after_lost_frames (10)
PERIOD_NS = round(1e9 / scene_config("loop").frame_rate_hz)  # nanoseconds between the synthetic loop's frames
ATE_BOUND_M = 0.02  # as test_run_synthetic: the loop tracks to a few mm over its first frames


@pytest.mark.slow(25)
def test_a_blacked_out_camera_is_relocalised_on_the_old_map(tmp_path: Path):
    config = tmp_path / "black.yaml"
    config.write_text(f"source:\n  faults:\n    - {{kind: black, first_frame: {BLACK[0]}, last_frame: {BLACK[1]}}}\n")
    command = [sys.executable, "-m", "zenslam.service.cli", "run", "synthetic", "--config", str(config),
               "--max-frames", str(FRAMES), "--output", str(tmp_path), "--run-id", "it-reloc", "--no-progress"]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    run_dir = tmp_path / "it-reloc"
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["relocalisation"]["count"] >= 1 and metrics["relocalisation"]["new_maps"] == 0
    assert metrics["relocalisation"]["frames_lost"] == BLACK[1] - BLACK[0] + 1
    posed = set((read_tum(run_dir / "trajectory.tum").stamps_ns // PERIOD_NS).tolist())
    assert not posed & set(range(BLACK[0], BLACK[1] + 1))
    back = min(k for k in posed if k > BLACK[1])
    assert back <= BLACK[1] + 3, f"relocalised at frame {back}, more than 3 frames after the images returned"
    assert set(range(back, FRAMES)) <= posed  # tracked on from there
    assert metrics["ate"]["rmse_m"] < ATE_BOUND_M
    assert "relocalised at frame" in (run_dir / "logs" / "frontend.log").read_text()
    assert np.isfinite(metrics["timing"]["relocalisation"]["max_ms"])
