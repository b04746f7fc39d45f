"""McapSource: a recording's sensor/frame channel played back as a Source, exactly as it was recorded."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, DatasetError, RecordingError, TimestampError
from zenslam.schemas import codec
from zenslam.service import mcap_io
from zenslam.service.sources import SensorFrame, open_source
from zenslam.service.sources.mcap_source import McapSource, sensor_frame_topic, write_frames

CAL = PinholeCalibration(50.0, 50.0, 31.5, 23.5, 64, 48, 0.1)
STEP_NS = 50_000_000  # 20 Hz


def _frames(n: int, rng: np.random.Generator, depth: bool = False) -> list[SensorFrame]:
    frames = []
    for i in range(n):
        left = rng.integers(0, 256, (48, 64), dtype=np.uint8)
        depth_m = rng.uniform(0.5, 5.0, (48, 64)).astype(np.float32) if depth else None
        right = None if depth else np.roll(left, -3, axis=1)
        frames.append(SensorFrame(10 + i, 1_000_000_000 + i * STEP_NS, left, right, depth_m))
    return frames


def test_frames_come_back_as_recorded(tmp_path):
    frames = _frames(5, np.random.default_rng(1))
    path = tmp_path / "run.mcap"
    assert write_frames(path, frames, CAL, "stereo", "synthetic:loop") == 5
    source = open_source(f"mcap:{path}")
    assert isinstance(source, McapSource)
    assert (len(source), source.sensor, source.calibration, source.name) == (5, "stereo", CAL, "synthetic:loop")
    np.testing.assert_array_equal(source.stamps_ns(), [f.stamp_ns for f in frames])
    for _ in range(2):  # iterable again: each pass reads the file anew
        played = list(source)
        assert [f.index for f in played] == [f.index for f in frames]  # the recorded indices, not renumbered
        for got, want in zip(played, frames):
            np.testing.assert_array_equal(got.left, want.left)
            np.testing.assert_array_equal(got.right, want.right)
            assert got.depth_m is None
    assert source.ground_truth() is None and source.imu() is None


def test_rgbd_depth_survives(tmp_path):
    frames = _frames(2, np.random.default_rng(2), depth=True)
    write_frames(tmp_path / "run.mcap", frames, CAL, "rgbd")
    source = McapSource(tmp_path / "run.mcap")
    assert source.sensor == "rgbd" and source.name == "run"  # no recorded name: the file's stem
    for got, want in zip(source, frames):
        np.testing.assert_array_equal(got.depth_m, want.depth_m)
        assert got.right is None


def test_frames_are_read_lazily(tmp_path, monkeypatch):
    write_frames(tmp_path / "run.mcap", _frames(4, np.random.default_rng(3)), CAL, "stereo")
    source = McapSource(tmp_path / "run.mcap")
    decoded = []
    original = codec.decode_sensor_frame
    monkeypatch.setattr(codec, "decode_sensor_frame", lambda data: decoded.append(1) or original(data))
    first = next(iter(source))
    assert first.index == 10 and len(decoded) == 1  # one frame decoded for one frame taken


def test_frames_by_position_read_on_and_restart_for_earlier_ones(tmp_path, monkeypatch):
    frames = _frames(5, np.random.default_rng(5))
    write_frames(tmp_path / "run.mcap", frames, CAL, "stereo")
    source = McapSource(tmp_path / "run.mcap")
    decoded = []
    original = codec.decode_sensor_frame
    monkeypatch.setattr(codec, "decode_sensor_frame", lambda data: decoded.append(1) or original(data))
    assert [source.frame(k).index for k in (0, 1, 3)] == [10, 11, 13]  # position k holds recorded index 10 + k
    assert len(decoded) == 4  # read on: frame 2 decoded on the way to 3, nothing twice
    np.testing.assert_array_equal(source.frame(1).left, frames[1].left)  # earlier: from the start again
    assert len(decoded) == 6
    with pytest.raises(DatasetError, match="has no frame 5: it has 5 frames"):
        source.frame(5)


def test_other_channels_are_ignored_and_only_sensor_frames_count(tmp_path):
    path = tmp_path / "run.mcap"
    frame = _frames(1, np.random.default_rng(4))[0]
    with mcap_io.RecordingWriter(path) as writer:
        status = codec.encode_stage_status(codec.StageStatusMessage("source", "running", 1))
        writer.write("/source/status", codec.STAGE_STATUS, status, 5)
        writer.write(sensor_frame_topic(), codec.SENSOR_FRAME, codec.encode_sensor_frame(frame, CAL, "stereo"), frame.stamp_ns)
    assert len(McapSource(path)) == 1


def test_a_recording_without_frames_says_what_is_needed(tmp_path):
    path = tmp_path / "run.mcap"
    with mcap_io.RecordingWriter(path) as writer:
        writer.write("/source/status", codec.STAGE_STATUS, codec.encode_stage_status(codec.StageStatusMessage("source", "running")), 5)
    with pytest.raises(DatasetError, match=r"no frames on /sensor/frame.*recorder enabled"):
        McapSource(path)


def test_not_an_mcap_file(tmp_path):
    path = tmp_path / "run.mcap"
    path.write_text("not a recording")
    with pytest.raises(RecordingError, match="not an MCAP file"):
        open_source(f"mcap:{path}")
    with pytest.raises(RecordingError, match="does not exist"):
        open_source(f"mcap:{tmp_path / 'missing.mcap'}")


def test_stamps_out_of_order_are_refused(tmp_path):
    frames = _frames(3, np.random.default_rng(5))
    frames[2] = SensorFrame(12, frames[0].stamp_ns, frames[2].left, frames[2].right)
    write_frames(tmp_path / "run.mcap", frames, CAL, "stereo")
    with pytest.raises(TimestampError, match="frame 12 has stamp 1000000000 ns"):
        McapSource(tmp_path / "run.mcap")


def test_a_change_of_camera_is_refused(tmp_path):
    path = tmp_path / "run.mcap"
    frames = _frames(2, np.random.default_rng(6))
    other = PinholeCalibration(60.0, 60.0, 31.5, 23.5, 64, 48, 0.1)
    with mcap_io.RecordingWriter(path) as writer:
        for frame, cal in zip(frames, (CAL, other)):
            writer.write(sensor_frame_topic(), codec.SENSOR_FRAME, codec.encode_sensor_frame(frame, cal, "stereo"), frame.stamp_ns)
    with pytest.raises(CalibrationError, match="frame 11"):
        McapSource(path)
