"""The source's ground truth in a recording: recorded from the bus like any message, read back by McapSource."""

from __future__ import annotations

import numpy as np

from zenslam.geometry import make_T
from zenslam.schemas import keys
from zenslam.service import mcap_io
from zenslam.service.recorded_ground_truth import SCHEMA, encode_ground_truth, ground_truth_topic, read_ground_truth
from zenslam.service.recorder import Recorder
from zenslam.service.run_config import RecorderConfig
from zenslam.service.sources.mcap_source import McapSource, write_frames
from zenslam.service.sources.synthetic import SyntheticSource, scene_config
from zenslam.trajectory import Trajectory

SESSION = "gt-test"


def _ground_truth(n: int = 30) -> Trajectory:
    """A turning camera of a y-down world, 20 Hz."""
    yaw = np.linspace(0.0, 1.0, n)
    rotations = [np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]) for a in yaw]
    poses = np.stack([make_T(R, [np.cos(a), 0.1 * a, np.sin(a)]) for R, a in zip(rotations, yaw)])
    return Trajectory(1_000_000_000 + np.arange(n, dtype=np.int64) * 50_000_000, poses)


def test_the_recorder_keeps_the_published_ground_truth(tmp_path):
    truth = _ground_truth()
    path = tmp_path / "run.mcap"
    with mcap_io.RecordingWriter(path) as writer:
        recorder = Recorder(writer, RecorderConfig(), SESSION)
        recorder.record(keys.source_ground_truth(SESSION), f"application/protobuf;{SCHEMA}", encode_ground_truth(truth))
    assert ground_truth_topic() == "/source/ground_truth"
    assert [m.topic for m in mcap_io.iter_messages(path)] == ["/source/ground_truth"]
    read = read_ground_truth(path)
    np.testing.assert_array_equal(read.stamps_ns, truth.stamps_ns)
    np.testing.assert_array_equal(read.T_world_cam, truth.T_world_cam)  # bit for bit: float64 as recorded


def test_a_recording_without_ground_truth_has_none(tmp_path):
    path = tmp_path / "old.mcap"
    with mcap_io.RecordingWriter(path) as writer:
        writer.write("/frontend/state", None, b"x", 1)
    assert read_ground_truth(path) is None


def test_mcap_source_gives_the_recorded_ground_truth(tmp_path):
    source = SyntheticSource(scene_config("loop", width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5))
    frames = [source.frame(i) for i in range(3)]
    truth = source.ground_truth()
    write_frames(tmp_path / "run.mcap", frames, source.calibration, source.sensor, source.name, ground_truth=truth)
    replayed = McapSource(tmp_path / "run.mcap")
    assert len(replayed) == 3  # the ground-truth channel does not disturb the frames
    np.testing.assert_array_equal(replayed.ground_truth().T_world_cam, truth.T_world_cam)
    np.testing.assert_array_equal(replayed.ground_truth().stamps_ns, truth.stamps_ns)
