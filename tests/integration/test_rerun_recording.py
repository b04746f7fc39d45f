"""A lockstep run writes one .rrd per logging stage process, all of one recording, and two runs log the same data.

Two lockstep runs of a short synthetic sequence (the ``zenslam run --lockstep`` command, and the same
run followed by this process; both shared with other modules by conftest.py). Each run folder must
hold frontend.rrd and backend.rrd (the source logs nothing) with the run id as recording id, the
documented entity paths, every frame on the frame timeline (the frontend's poses; its images of every
``rerun.image_every_n``-th frame) and the
backend's entries at its keyframes' frames. On the frame timeline both runs must log identical
values, measured timings (and the backend's queue depth, which depends on when the inbox is
looked at) aside.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from zenslam.runtime.rerun_config import RerunConfig
from zenslam.runtime.rerun_log import read_rrd, recording_ids

pytestmark = pytest.mark.integration

ENTITIES = {
    "frontend": {"/frontend/camera/left", "/frontend/keypoints", "/frontend/matches", "/frontend/pose", "/frontend/state", "/frontend/counts/tracked",
                 "/frontend/timing/total", "/frontend/timing/extraction", "/frontend/pose/camera"},
    "backend": {"/backend/keyframes", "/backend/map_points", "/backend/covisibility", "/backend/trajectory",
                "/backend/local_ba/before", "/backend/local_ba/after", "/backend/timing/local_ba", "/backend/timing/total",
                "/backend/counts/map_points", "/backend/counts/queue_depth"},
}  # fmt: skip


@pytest.fixture(scope="module")
def runs(command_run, tracked_run) -> tuple[Path, Path]:
    return command_run.run_dir, tracked_run.run_dir


def _frames(data: dict, entity: str) -> set[int | None]:
    return {frame for (path, _, frame) in data if path == entity}


def _comparable(data: dict) -> dict:
    """What must repeat between lockstep runs: everything but measured times and the inbox depth."""
    return {key: cells for key, cells in data.items() if "/timing/" not in key[0] and key[0] != "/backend/counts/queue_depth"}


def test_each_stage_writes_its_rrd_of_the_run_recording(runs):
    run_dir = runs[0]
    run_id = run_dir.name
    assert sorted(p.name for p in run_dir.glob("*.rrd")) == ["backend.rrd", "frontend.rrd"]
    for stage, entities in ENTITIES.items():
        path = run_dir / f"{stage}.rrd"
        assert recording_ids(path) == [("zenslam", run_id)]
        logged = {key[0] for key in read_rrd(path)}
        assert entities <= logged, f"{path} lacks {sorted(entities - logged)}"


def test_every_frame_is_on_the_frame_timeline(runs, command_run):
    run_dir, frames = runs[0], command_run.frames
    metrics = json.loads((run_dir / "metrics.json").read_text())
    frontend, backend = (read_rrd(run_dir / f"{stage}.rrd") for stage in ("frontend", "backend"))
    every_n = RerunConfig().image_every_n  # the frontend logs every n-th image
    assert _frames(frontend, "/frontend/camera/left") == set(range(0, frames, every_n))
    assert _frames(frontend, "/frontend/pose") == set(range(frames))  # the synthetic loop tracks every frame
    assert _frames(frontend, "/frontend/keypoints") == set(range(frames))
    keyframe_frames = _frames(backend, "/backend/keyframes")
    assert len(keyframe_frames) == metrics["keyframes"]["processed"] >= 3
    assert keyframe_frames <= set(range(frames)) and 0 in keyframe_frames
    assert _frames(backend, "/backend/local_ba/after") <= keyframe_frames


def test_two_lockstep_runs_log_the_same_data(runs):
    for stage in ("frontend", "backend"):
        a, b = (_comparable(read_rrd(run / f"{stage}.rrd")) for run in runs)
        assert a.keys() == b.keys(), f"{stage}: entities/frames differ: {sorted(set(a) ^ set(b))[:10]}"
        differing = sorted((key for key in a if a[key] != b[key]), key=str)
        assert not differing, f"{stage}: values differ between two lockstep runs at {differing[:10]}"
