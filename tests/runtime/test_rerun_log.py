"""The stage recordings: the file each stage writes and its timelines (the stage loggers' own tests sit beside them)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from zenslam.runtime import rerun_log
from zenslam.runtime.rerun_log import RerunConfig, StageRecording, read_rrd, recording_ids



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
