"""Runs that several integration modules check, each made once.

``tracked_run``: the stages driven in this process by ``track()``, as ``zenslam run`` does;
``command_run``: the ``zenslam run --lockstep`` command itself, in its own process tree. Both
run the same frames of the synthetic loop with the default configuration (recorder and rerun on),
so lockstep determinism says they must write the same trajectories and log the same data.
``kitti_lockstep_run``: ``zenslam run --lockstep`` on the KITTI 06 clip, rerun off.

The tests that use one of them run on one pytest-xdist worker (tests/conftest.py groups them),
where each session-scoped run is made once.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from zenslam.runtime.rerun_config import RerunConfig
from zenslam.service.commands.run import track
from zenslam.service.run_config import RecorderConfig, RunConfig, SourceConfig, run_config_to_yaml
from zenslam.service.run_output import RunResult, RunLog, prepare_run_dir, write_config, write_outputs
from zenslam.service.sources import open_source

SYNTHETIC_FRAMES = 30


@dataclass(frozen=True)
class TrackedRun:
    frames: int
    run_dir: Path
    log: RunLog
    result: RunResult


@dataclass(frozen=True)
class CommandRun:
    frames: int
    run_dir: Path
    stdout: str


@pytest.fixture(scope="session")
def tracked_run(tmp_path_factory) -> TrackedRun:
    output = tmp_path_factory.mktemp("tracked")
    config = RunConfig(source=SourceConfig(spec="synthetic", max_frames=SYNTHETIC_FRAMES))
    run_dir = prepare_run_dir(output, "it-tracked")
    config_path = write_config(run_dir, config)
    source = open_source(config.source.spec)
    log, completed, failure = track(config, "it-tracked", run_dir, config_path, source, progress=False)
    assert completed and failure is None
    result = write_outputs(run_dir, log, source.ground_truth(), config.evaluation)
    return TrackedRun(SYNTHETIC_FRAMES, run_dir, log, result)


@pytest.fixture(scope="session")
def command_run(tmp_path_factory) -> CommandRun:
    output = tmp_path_factory.mktemp("command")
    command = [sys.executable, "-m", "zenslam.service.cli", "run", "synthetic", "--lockstep", "--max-frames",
               str(SYNTHETIC_FRAMES), "--output", str(output), "--run-id", "it-command", "--no-progress"]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    return CommandRun(SYNTHETIC_FRAMES, output / "it-command", result.stdout)


@pytest.fixture(scope="session")
def kitti_lockstep_run(kitti_root: Path, tmp_path_factory) -> Path:
    """The run folder (run.mcap, metrics.json, ...) of a lockstep run of the KITTI 06 clip; rerun is off
    (its users check the recording and the metrics), the viewer images are JPEG."""
    output = tmp_path_factory.mktemp("kitti")
    config = output / "config.yaml"
    config.write_text(run_config_to_yaml(RunConfig(rerun=RerunConfig(enabled=False), recorder=RecorderConfig(image_format="jpeg"))))
    command = [sys.executable, "-m", "zenslam.service.cli", "run", f"kitti:{kitti_root / 'sequences' / '06'}", "--lockstep",
               "--config", str(config), "--output", str(output), "--run-id", "kitti", "--no-progress"]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=900, cwd=output)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    return output / "kitti"
