"""What the backend logs to its rerun recording: the map, its graphs, local BA errors, counts, timings and queue depth."""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from zenslam.backend.rerun_log import BackendLog
from zenslam.runtime.rerun_log import RerunConfig, StageRecording, read_rrd

TIMINGS_MS = {"local_ba": 12.0, "total": 20.0}


def _frames(data: dict, entity: str, component: str) -> list[int | None]:
    """The frame indices at which ``entity`` logged ``component``, ascending (None = static, first)."""
    return sorted((k[2] for k in data if k[0] == entity and k[1] == component), key=lambda f: -1 if f is None else f)


def _value(data: dict, entity: str, component: str, frame: int | None) -> list:
    (cell,) = data[(entity, component, frame)]
    return cell.to_pylist()[0]


@dataclass
class _Keyframe:
    id: int
    stamp_ns: int
    centre_world: np.ndarray


def _map() -> SimpleNamespace:
    """What BackendLog reads of a BackendMap: keyframes, points, covisibility and loop edges."""
    keyframes = {i: _Keyframe(i, 100 * i, np.array([float(i), 0.0, 0.0])) for i in (2, 0, 1)}  # insertion order != time order
    points = {5: SimpleNamespace(p_world=np.array([0.0, 1.0, 5.0])), 3: SimpleNamespace(p_world=np.array([1.0, 1.0, 4.0]))}
    graph = SimpleNamespace(edges=lambda: [(0, 1, 40), (0, 2, 20), (1, 2, 30)])
    essential = SimpleNamespace(loop_edges=lambda: [(0, 2)])
    return SimpleNamespace(keyframes=keyframes, points=points, covisibility=graph, essential_graph=essential)


def _keyframe(frame: int, stamp_ns: int) -> SimpleNamespace:
    return SimpleNamespace(frame_index=frame, stamp_ns=stamp_ns)


def test_the_backend_logs_the_map_its_graphs_local_ba_counts_and_timings(tmp_path):
    with StageRecording(tmp_path, "r", "backend", RerunConfig()) as recording:
        backend = BackendLog(recording)
        backend.log_keyframe(_keyframe(4, 400), _map(), {}, TIMINGS_MS)
        backend.log_keyframe(_keyframe(9, 900), _map(), {"initial_error": 9.0, "final_error": 1.0}, TIMINGS_MS)
        backend.log_queue_depth(_keyframe(9, 900), 2)
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
            backend.log_keyframe(_keyframe(frame, stamp_ns), _map(), {}, TIMINGS_MS)
        backend.finish()
    data = read_rrd(tmp_path / "backend.rrd")
    # 0.4 s and 1.3 s came within a second of the previous map; 1.3 s is the last: logged by finish().
    assert _frames(data, "/backend/map_points", "Points3D:positions") == [0, 2, 3]
    assert _frames(data, "/backend/covisibility", "LineStrips3D:strips") == [0, 2, 3]
    assert _frames(data, "/backend/keyframes", "Points3D:positions") == [0, 1, 2, 3]  # small: every keyframe
    with StageRecording(tmp_path, "r", "backend", RerunConfig(map_period_s=0.0)) as recording:
        backend = BackendLog(recording)
        for frame, stamp_ns in enumerate(stamps_ns):
            backend.log_keyframe(_keyframe(frame, stamp_ns), _map(), {}, TIMINGS_MS)
        backend.finish()
    assert _frames(read_rrd(tmp_path / "backend.rrd"), "/backend/map_points", "Points3D:positions") == [0, 1, 2, 3]
