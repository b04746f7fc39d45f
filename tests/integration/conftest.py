"""Two lockstep runs of the synthetic loop that several integration modules check, each made once.

``tracked_run``: the stages driven in this process by ``track()``, as ``zenslam run`` does;
``command_run``: the ``zenslam run --lockstep`` command itself, in its own process tree. Both
run the same frames with the default configuration (recorder and rerun on), so lockstep
determinism says they must write the same trajectories and log the same data.

The tests that use them run on one pytest-xdist worker (tests/conftest.py groups them), where each
session-scoped run is made once.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from zenslam.service.commands.run import track
from zenslam.service.run_config import RunConfig, SourceConfig
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
    log, completed = track(config, "it-tracked", run_dir, config_path, source, progress=False)
    assert completed
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
