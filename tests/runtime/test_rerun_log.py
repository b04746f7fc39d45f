"""The stage recordings: the file each stage writes, its timelines, and what the stage loggers put in it."""

from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.runtime import rerun_log
from zenslam.runtime.rerun_log import FrontendLog, RerunConfig, StageRecording, read_rrd, recording_ids
from zenslam.service.sources.frame import SensorFrame

CALIBRATION = PinholeCalibration(400.0, 400.0, 80.0, 60.0, 160, 120, 0.1)


def _frames(data: dict, entity: str, component: str) -> list[int | None]:
    """The frame indices at which ``entity`` logged ``component``, ascending (None = static, first)."""
    return sorted((k[2] for k in data if k[0] == entity and k[1] == component), key=lambda f: -1 if f is None else f)


def _value(data: dict, entity: str, component: str, frame: int | None) -> list:
    (cell,) = data[(entity, component, frame)]
    return cell.to_pylist()[0]


def test_sensor_time_is_a_duration_for_stamps_from_zero_and_a_timestamp_for_epoch_stamps():
    assert rerun_log.sensor_time(103_000_000) == {"duration": np.timedelta64(103_000_000, "ns")}
    euroc = 1_403_715_273_262_142_976
    assert rerun_log.sensor_time(euroc) == {"timestamp": np.datetime64(euroc, "ns")}


def test_a_stage_recording_is_its_own_file_of_the_run_recording_with_explicit_timelines_only(tmp_path):
    with StageRecording(tmp_path, "run-42", "frontend", RerunConfig()) as recording:
        recording.at(3, 150_000_000)
        recording.scalars("frontend/timing", {"b": 2.0, "a": 1.0})
    path = tmp_path / "frontend.rrd"
    assert recording.path == path and path.stat().st_size > 0
    assert recording_ids(path) == [("zenslam", "run-42")]
    from rerun.chunk import RrdReader

    assert RrdReader(path).blueprints(), "the default blueprint is saved with the recording"
    timelines = {name for chunk in RrdReader(path).store().stream().to_chunks() for name in chunk.timeline_names}
    assert timelines == {"frame", "sensor_time"}  # no wall-clock log_time, no log_tick
    data = read_rrd(path)
    assert set(data) == {("/frontend/timing/a", "Scalars:scalars", 3), ("/frontend/timing/b", "Scalars:scalars", 3)}
    assert _value(data, "/frontend/timing/b", "Scalars:scalars", 3) == [2.0]


def test_open_stage_recording_writes_beside_the_config_or_nothing(tmp_path):
    config_path = tmp_path / "run" / "config.yaml"
    with rerun_log.open_stage_recording("backend", "r", config_path, RerunConfig()) as recording:
        assert recording is not None
    assert (tmp_path / "run" / "backend.rrd").is_file()
    with rerun_log.open_stage_recording("backend", "r", config_path, RerunConfig(enabled=False)) as recording:
        assert recording is None
    with rerun_log.open_stage_recording("backend", "r", None, RerunConfig()) as recording:
        assert recording is None


def _output(index: int, state: str = "ok", lost_reason: str | None = None, T=None, n_tracked: int = 2) -> SimpleNamespace:
    return SimpleNamespace(
        index=index, stamp_ns=index * 100_000_000, state=state, lost_reason=lost_reason,
        T_world_cam=T, n_tracked=n_tracked, timings_ms={"extraction": 1.5, "total": 3.0},
    )  # fmt: skip


@pytest.mark.parametrize("jpeg", [False, True])
def test_the_frontend_logs_every_nth_left_image(tmp_path, jpeg):
    image = np.random.default_rng(0).integers(0, 255, (120, 160), dtype=np.uint8)
    with StageRecording(tmp_path, "r", "frontend", RerunConfig(image_every_n=2, jpeg=jpeg)) as recording:
        frontend = FrontendLog(recording)
        for index in range(5):
            frontend.log_frame(_output(index), left=image)
        frontend.log_frame(_output(6))  # no image at hand: none logged
    data = read_rrd(tmp_path / "frontend.rrd")
    component = "EncodedImage:blob" if jpeg else "Image:buffer"
    assert _frames(data, "/frontend/camera/left", component) == [0, 2, 4]
    (buffer,) = _value(data, "/frontend/camera/left", component, 2)
    if jpeg:  # a JPEG of the image (lossy: noise is the worst case for it)
        decoded = cv2.imdecode(np.frombuffer(bytes(buffer), np.uint8), cv2.IMREAD_UNCHANGED)
        assert decoded.shape == image.shape and np.abs(decoded.astype(int) - image).mean() < 25
    else:
        assert bytes(buffer) == image.tobytes()


def test_the_frontend_logs_keypoints_tracked_points_pose_state_counts_and_timings(tmp_path):
    px = np.array([[10, 20], [30, 40], [50, 60]], dtype=np.float32)
    tracked = np.array([True, False, True])
    T = np.eye(4)
    T[:3, 3] = [1.0, -2.0, 0.5]
    with StageRecording(tmp_path, "r", "frontend", RerunConfig()) as recording:
        frontend = FrontendLog(recording)
        frontend.log_camera(CALIBRATION)
        frontend.log_frame(_output(0, T=T), (px, tracked))
        frontend.log_frame(_output(1, T=T), (px, tracked))  # same state: no new state line
        frontend.log_frame(_output(2, state="lost", lost_reason="too_few_matches", n_tracked=0))
    data = read_rrd(tmp_path / "frontend.rrd")
    assert _value(data, "/frontend/keypoints", "Points2D:positions", 0) == px.tolist()
    assert _value(data, "/frontend/matches", "Points2D:positions", 1) == px[tracked].tolist()
    assert _frames(data, "/frontend/pose", "Transform3D:translation") == [0, 1]  # lost: no pose
    assert _value(data, "/frontend/pose", "Transform3D:translation", 1) == [[1.0, -2.0, 0.5]]
    assert _frames(data, "/frontend/state", "TextLog:text") == [0, 2]
    assert _value(data, "/frontend/state", "TextLog:text", 2) == ["lost: too_few_matches"]
    assert _frames(data, "/frontend/counts/tracked", "Scalars:scalars") == [0, 1, 2]
    assert _value(data, "/frontend/timing/extraction", "Scalars:scalars", 2) == [1.5]
    assert _frames(data, "/frontend/pose/camera", "Pinhole:image_from_camera") == [None]  # static frustum


def test_tracked_keypoints_come_from_the_trackers_last_frame_of_that_index():
    frame = SimpleNamespace(index=7, features=SimpleNamespace(px=np.array([[1.0, 2.0], [3.0, 4.0]])))
    pipeline = SimpleNamespace(tracker=SimpleNamespace(_last=SimpleNamespace(frame=frame, rows=np.array([-1, 5]))))
    px, tracked = rerun_log.tracked_keypoints(pipeline, 7)
    np.testing.assert_array_equal(px, [[1.0, 2.0], [3.0, 4.0]])
    np.testing.assert_array_equal(tracked, [False, True])
    assert rerun_log.tracked_keypoints(pipeline, 8) is None  # frame 8 was lost: the tracker kept frame 7
    assert rerun_log.tracked_keypoints(SimpleNamespace(), 7) is None


def test_a_stage_recording_keeps_pandas_out_of_the_stage_process(tmp_path):
    # In a fresh interpreter, as in a stage process: pyarrow would import pandas on rerun's first log.
    code = f"""
import sys
import numpy as np
import rerun as rr
from rerun.chunk import RrdReader
from zenslam.runtime.rerun_log import StageRecording
from zenslam.service.run_config import RerunConfig
with StageRecording({str(tmp_path)!r}, "r", "backend", RerunConfig()) as recording:
    recording.at(0, 0)
    recording.log("backend/map_points", rr.Points3D(np.zeros((4, 3))))
    recording.log("frontend/state", rr.TextLog("ok"))
print("pandas" in sys.modules, bool(RrdReader({str(tmp_path / "backend.rrd")!r}).blueprints()))
import pandas  # still importable by whoever needs it
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0 and "Warning" not in result.stderr, result.stderr[-2000:]
    assert result.stdout.split() == ["False", "True"]
