"""The stage recordings: the file each stage writes, its timelines, and what the stage loggers put in it."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.runtime import rerun_log
from zenslam.runtime.rerun_log import BackendLog, RerunConfig, StageRecording, read_rrd, recording_ids
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


@dataclass
class _Keyframe:
    id: int
    stamp_ns: int
    centre_world: np.ndarray


@dataclass
class _Mapper:
    """What BackendLog reads of a LocalMapper: the map (keyframes, points, covisibility), BA stats, timings."""

    map: SimpleNamespace
    last_ba_stats: dict = field(default_factory=dict)
    last_timings_ms: dict = field(default_factory=lambda: {"local_ba": 12.0, "total": 20.0})


def _mapper(ba: bool) -> _Mapper:
    keyframes = {i: _Keyframe(i, 100 * i, np.array([float(i), 0.0, 0.0])) for i in (2, 0, 1)}  # insertion order != time order
    points = {5: SimpleNamespace(p_world=np.array([0.0, 1.0, 5.0])), 3: SimpleNamespace(p_world=np.array([1.0, 1.0, 4.0]))}
    graph = SimpleNamespace(edges=lambda: [(0, 1, 40), (0, 2, 20), (1, 2, 30)])
    stats = {"initial_error": 9.0, "final_error": 1.0} if ba else {}
    essential = SimpleNamespace(loop_edges=lambda: [(0, 2)])
    return _Mapper(SimpleNamespace(keyframes=keyframes, points=points, covisibility=graph, essential_graph=essential), stats)


def test_the_backend_logs_the_map_its_graphs_local_ba_counts_and_timings(tmp_path):
    with StageRecording(tmp_path, "r", "backend", RerunConfig()) as recording:
        backend = BackendLog(recording)
        backend.log_keyframe(SimpleNamespace(frame_index=4, stamp_ns=400), _mapper(ba=False))
        backend.log_keyframe(SimpleNamespace(frame_index=9, stamp_ns=900), _mapper(ba=True))
        backend.log_queue_depth(SimpleNamespace(frame_index=9, stamp_ns=900), 2)
        backend.finish()  # frame 9 came within map_period_s of frame 4: its map is the final one
    data = read_rrd(tmp_path / "backend.rrd")
    assert _value(data, "/backend/keyframes", "Points3D:positions", 9) == [[0, 0, 0], [1, 0, 0], [2, 0, 0]]
    assert _value(data, "/backend/trajectory", "LineStrips3D:strips", 9) == [[[0, 0, 0], [1, 0, 0], [2, 0, 0]]]
    assert _value(data, "/backend/map_points", "Points3D:positions", 9) == [[1, 1, 4], [0, 1, 5]]  # ids ascending
    strips = _value(data, "/backend/covisibility", "LineStrips3D:strips", 4)
    assert strips == [[[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [2, 0, 0]], [[1, 0, 0], [2, 0, 0]]]
    assert _value(data, "/backend/loops", "LineStrips3D:strips", 4) == [[[0, 0, 0], [2, 0, 0]]]
    assert _frames(data, "/backend/local_ba/before", "Scalars:scalars") == [9]  # no BA at frame 4
    assert _value(data, "/backend/local_ba/after", "Scalars:scalars", 9) == [1.0]
    assert _value(data, "/backend/counts/map_points", "Scalars:scalars", 4) == [2.0]
    assert _value(data, "/backend/counts/queue_depth", "Scalars:scalars", 9) == [2.0]
    assert _frames(data, "/backend/timing/local_ba", "Scalars:scalars") == [4, 9]


def test_the_backend_logs_the_map_at_most_once_per_period_and_the_final_map(tmp_path):
    stamps_ns = (0, 400_000_000, 1_000_000_000, 1_300_000_000)
    with StageRecording(tmp_path, "r", "backend", RerunConfig(map_period_s=1.0)) as recording:
        backend = BackendLog(recording)
        for frame, stamp_ns in enumerate(stamps_ns):
            backend.log_keyframe(SimpleNamespace(frame_index=frame, stamp_ns=stamp_ns), _mapper(ba=False))
        backend.finish()
    data = read_rrd(tmp_path / "backend.rrd")
    # 0.4 s and 1.3 s came within a second of the previous map; 1.3 s is the last: logged by finish().
    assert _frames(data, "/backend/map_points", "Points3D:positions") == [0, 2, 3]
    assert _frames(data, "/backend/covisibility", "LineStrips3D:strips") == [0, 2, 3]
    assert _frames(data, "/backend/keyframes", "Points3D:positions") == [0, 1, 2, 3]  # small: every keyframe
    with StageRecording(tmp_path, "r", "backend", RerunConfig(map_period_s=0.0)) as recording:
        backend = BackendLog(recording)
        for frame, stamp_ns in enumerate(stamps_ns):
            backend.log_keyframe(SimpleNamespace(frame_index=frame, stamp_ns=stamp_ns), _mapper(ba=False))
        backend.finish()
    assert _frames(read_rrd(tmp_path / "backend.rrd"), "/backend/map_points", "Points3D:positions") == [0, 1, 2, 3]


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
