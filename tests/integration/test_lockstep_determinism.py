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
