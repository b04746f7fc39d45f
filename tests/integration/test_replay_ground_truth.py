"""A run's recording keeps its source's ground truth, so ``zenslam replay`` scores the replayed run too."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from zenslam.service.recorded_ground_truth import read_ground_truth
from zenslam.service.run_config import RecorderConfig, RerunConfig, RunConfig, SourceConfig, run_config_to_yaml
from zenslam.service.sources.mcap_source import write_frames
from zenslam.service.sources.synthetic import SyntheticSource, scene_config

pytestmark = pytest.mark.integration

FRAMES = 12


def _zenslam(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "zenslam.service.cli", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=900, cwd=cwd)


def _small_loop(path: Path) -> None:
    """The synthetic loop's first frames at 256x192 (same field of view) with their ground truth."""
    default = scene_config("loop")
    scale = 256 / default.width
    scene = scene_config("loop", width=256, height=192, fx=default.fx * scale, fy=default.fy * scale, cx=127.5, cy=95.5)
    source = SyntheticSource(scene)
    frames = (source.frame(i) for i in range(FRAMES))
    write_frames(path, frames, source.calibration, source.sensor, source.name, ground_truth=source.ground_truth())


@pytest.mark.slow(10)
def test_a_recorded_synthetic_run_replays_with_its_ate(tmp_path):
    _small_loop(tmp_path / "input.mcap")
    config = RunConfig(
        source=SourceConfig(spec=f"mcap:{tmp_path / 'input.mcap'}"),
        mode="lockstep",
        rerun=RerunConfig(enabled=False),
        recorder=RecorderConfig(image_format="jpeg"),
    )
    (tmp_path / "config.yaml").write_text(run_config_to_yaml(config))
    first = _zenslam("run", "--config", "config.yaml", "--output", ".", "--run-id", "first", "--no-progress", cwd=tmp_path)
    assert first.returncode == 0, first.stdout[-2000:] + first.stderr[-3000:]
    recorded = read_ground_truth(tmp_path / "first" / "run.mcap")
    assert recorded is not None and len(recorded) >= FRAMES  # the run put its source's ground truth in run.mcap
    assert "ate" in json.loads((tmp_path / "first" / "metrics.json").read_text())

    again = _zenslam("replay", "first/run.mcap", "--output", ".", "--run-id", "again", "--no-progress", cwd=tmp_path)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-3000:]
    metrics = json.loads((tmp_path / "again" / "metrics.json").read_text())
    assert "evaluation_error" not in metrics
    assert metrics["ate"]["matched_poses"] == FRAMES
    assert metrics["ate"]["rmse_m"] < 0.05  # lockstep replay of a clean synthetic clip: centimetres
