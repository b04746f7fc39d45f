"""Recording end to end: a lockstep ``zenslam run`` writes run.mcap with every message, viewers' types and
an index; rerun's own MCAP reader opens it; a recorder killed with SIGKILL loses at most its open chunk."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from zenslam.camera import PinholeCalibration
from zenslam.schemas import codec, keys
from zenslam.schemas.map_update import MapUpdate
from zenslam.runtime import bus
from zenslam.service import mcap_io
from zenslam.service.commands.export import export_recording
from zenslam.service.evaluation.trajectory_io import read_tum
from zenslam.service.replay import MAP_UPDATE_TOPIC, read_topics
from zenslam.service.recorder_config import RecorderConfig
from zenslam.service.sources import SensorFrame

pytestmark = pytest.mark.integration

VIEWER_SCHEMAS = {
    "/camera/left": "foxglove.CompressedImage",
    "/camera/right": "foxglove.CompressedImage",
    "/frontend/pose": "foxglove.PoseInFrame",
    "/tf": "foxglove.FrameTransform",
    "/map/points": "foxglove.PointCloud",
    "/sensor/frame": "zenslam.SensorFrame",
    "/frontend/keyframe": "zenslam.Keyframe",
    "/backend/map_update": "zenslam.MapUpdate",
}


@pytest.fixture(scope="module")
def recorded_run(tracked_run):
    """The shared lockstep run of conftest.py, recorded with the default recorder settings."""
    return tracked_run.run_dir, tracked_run.log, tracked_run.frames


def _summary(path: Path):
    with open(path, "rb") as f:
        return make_reader(f).get_summary()


def test_the_run_writes_an_indexed_recording_with_viewer_schemas(recorded_run):
    run_dir, log, frames = recorded_run
    summary = _summary(run_dir / "run.mcap")  # the summary and index are there: the recorder finished
    schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert {t: schemas.get(t) for t in VIEWER_SCHEMAS} == VIEWER_SCHEMAS
    counts = {c.topic: summary.statistics.channel_message_counts[i] for i, c in summary.channels.items()}
    tracked = sum(1 for s in log.states.values() if s.has_pose)
    assert counts["/frontend/pose"] == tracked == len(log.poses) == frames
    assert counts["/tf"] == tracked
    assert counts["/sensor/frame"] == frames + 1  # and its end of stream
    assert counts["/camera/left"] == counts["/camera/right"] == frames
    assert counts["/frontend/state"] == frames + 1
    # One answer per keyframe, the corrections the answers announce (local BA answered after its
    # keyframe, loop corrections), and the end of stream.
    updates = [codec.decode_map_update(m.data) for m in read_topics(run_dir / "run.mcap", (MAP_UPDATE_TOPIC,))[MAP_UPDATE_TOPIC]]
    answers = [u for u in updates if isinstance(u, MapUpdate) and u.answers_keyframe]
    assert len(answers) == log.keyframe_counts()["processed"]
    announced = sum(u.corrections_following for u in updates if isinstance(u, MapUpdate))
    assert counts["/backend/map_update"] == len(updates) == len(answers) + announced + 1
    # The first map, the final one, and at most one per recorder.map_points_period_s of sensor time between.
    stamps = sorted(log.poses)
    between = int((stamps[-1] - stamps[0]) / 1e9 / RecorderConfig().map_points_period_s)
    assert 2 <= counts["/map/points"] <= 2 + between < frames


def test_every_recorded_pose_is_the_one_the_run_saw(recorded_run):
    run_dir, log, _ = recorded_run
    recorded = {p.stamp_ns: p.T_world_cam for _, p in mcap_io.iter_decoded(run_dir / "run.mcap", ["/frontend/pose"])}
    assert set(recorded) == set(log.poses)
    for stamp_ns, T in log.poses.items():
        np.testing.assert_allclose(recorded[stamp_ns], T, atol=1e-12)


def test_export_gives_the_run_trajectory(recorded_run, tmp_path):
    run_dir, _, _ = recorded_run
    result = export_recording(run_dir / "run.mcap", tmp_path)
    exported, written = read_tum(result.written["trajectory.tum"]), read_tum(run_dir / "trajectory.tum")
    np.testing.assert_array_equal(exported.stamps_ns, written.stamps_ns)
    np.testing.assert_allclose(exported.T_world_cam, written.T_world_cam, atol=1e-8)
    assert result.keyframes >= 1 and result.points > 100


def test_rerun_opens_the_recording_with_its_own_mcap_reader(recorded_run):
    import rerun.chunk

    run_dir, _, _ = recorded_run
    columns: dict[str, set[str]] = {}
    for chunk in rerun.chunk.McapReader(run_dir / "run.mcap").stream():
        columns.setdefault(str(chunk.entity_path), set()).update(f.name for f in chunk.to_record_batch().schema)
    assert "EncodedImage:blob" in columns["/camera/left"]
    assert "Transform3D:translation" in columns["/tf"]
    assert "Points3D:positions" in columns["/map/points"]
    assert "InstancePoses3D:translations" in columns["/frontend/pose"]
    assert "zenslam.Keyframe:message" in columns["/frontend/keyframe"]  # decoded from the embedded schema


# ---- a recorder killed with SIGKILL ----

CAL = PinholeCalibration(50.0, 50.0, 32.0, 24.0, 64, 48, 0.1)
CHUNK_SIZE = 64 * 1024  # bytes


def _frame(i: int, rng: np.random.Generator) -> bytes:
    left = rng.integers(0, 256, (48, 64), dtype=np.uint8)  # noise: neither PNG nor zstd shrinks it
    return codec.encode_sensor_frame(SensorFrame(i, 1_000_000 * (i + 1), left, np.roll(left, 2, axis=1)), CAL, "stereo")


def _frames_per_chunk(frame: bytes) -> int:
    """A chunk holds fewer frames than CHUNK_SIZE / raw size (noise does not shrink as PNG, and the viewer
    images share the chunk): at most this many, which a kill may lose."""
    return CHUNK_SIZE // len(frame) + 1


def _written_frames(recording: Path, probe: Path) -> int:
    """Frames in the finished chunks of a recording still being written."""
    try:
        return mcap_io.recover(recording, probe).messages.get("/sensor/frame", 0)
    except (OSError, mcap_io.RecordingError):  # not created yet, or not past its magic bytes
        return 0


def test_a_killed_recorder_loses_at_most_its_open_chunk(tmp_path):
    rng = np.random.default_rng(7)
    session = "it-kill"
    config_path = tmp_path / "config.yaml"
    config_path.write_text(f"recorder:\n  chunk_size: {CHUNK_SIZE}\n")
    recording = tmp_path / "run.mcap"
    hub = bus.free_tcp_endpoint()
    published = int(rng.integers(30, 80))  # the random point: the kill comes after this many frames
    with bus.open_session(bus.BusConfig(listen=(hub,))) as hub_session:
        recorder = subprocess.Popen(
            [sys.executable, "-m", "zenslam.service.recorder", "--session", session, "--config", str(config_path),
             "--connect", hub, "--output", str(recording)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        try:
            assert not bus.wait_for_alive(hub_session, session, ["recorder"], timeout_s=30.0)
            publisher = bus.declare_publisher(hub_session, keys.sensor_frame(session), codec.SENSOR_FRAME, "lossless")
            assert bus.wait_for_subscribers(publisher, timeout_s=10.0)
            frames = [_frame(i, rng) for i in range(published)]
            for data in frames:
                publisher.put(data)
            # Wait until the writer has taken the frames, so that only the open chunk is unwritten.
            deadline = time.monotonic() + 60.0
            while _written_frames(recording, tmp_path / "probe.mcap") < published - _frames_per_chunk(frames[0]):
                assert time.monotonic() < deadline, "the recorder did not write the frames' chunks"
                time.sleep(0.05)
            recorder.kill()
            recorder.wait(timeout=10)
        finally:
            if recorder.poll() is None:
                recorder.kill()
    assert not mcap_io.has_summary(recording)
    report = mcap_io.recover(recording, tmp_path / "fixed.mcap")
    assert not report.complete
    kept = [m for m in mcap_io.iter_messages(tmp_path / "fixed.mcap", ["/sensor/frame"])]
    per_chunk = _frames_per_chunk(frames[0])
    assert published - per_chunk <= len(kept) <= published
    assert len(kept) > 0 and [m.sequence for m in kept] == list(range(len(kept)))
    for message, data in zip(kept, frames):  # in order, pixel for pixel (stored as PNG)
        stored, sent = codec.decode_sensor_frame(message.data).frame, codec.decode_sensor_frame(data).frame
        assert stored.index == sent.index
        np.testing.assert_array_equal(stored.left, sent.left)
        np.testing.assert_array_equal(stored.right, sent.right)
    assert report.messages["/sensor/frame"] == len(kept)
