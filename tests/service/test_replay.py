"""Replay comparisons: field paths of differences, ignored timings, counts, the earliest difference, backend replay."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from zenslam.backend.node import BackendNode
from zenslam.camera import PinholeCalibration
from zenslam.geometry import make_T, so3_exp
from zenslam.schemas import codec
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.service import mcap_io, replay
from zenslam.service.cli import build_parser
from zenslam.service.commands import replay as replay_command
from zenslam.service.run_config import BackendConfig, RunConfig, SourceConfig, run_config_to_yaml

CAL = PinholeCalibration(50.0, 50.0, 31.5, 23.5, 64, 48, 0.1)
STEP_NS = 100_000_000


def _T(i: int) -> np.ndarray:
    return make_T(so3_exp(np.array([0.0, 0.01 * i, 0.0])), np.array([0.1 * i, 0.0, 0.0]))


def _state(i: int, timings_ms: float = 1.0, n_tracked: int = 100) -> bytes:
    state = codec.TrackingStateMessage(i, i * STEP_NS, "ok", n_tracked=n_tracked, timings_ms={"total": timings_ms, "orb": 0.5}, has_pose=True)
    return codec.encode_tracking_state(state)


def _update(i: int, p_world: np.ndarray | None = None) -> bytes:
    p = np.arange(6, dtype=float).reshape(2, 3) if p_world is None else p_world
    corrections = tuple(KeyframeCorrection(k, _T(k), np.array([k, -1], dtype=np.int64)) for k in range(i + 1))
    update = MapUpdate(
        keyframe_id=i, stamp_ns=i * STEP_NS, keyframes=corrections, point_ids=np.array([1, 2], dtype=np.int64), p_world=p,
        descriptors=np.zeros((2, 32), np.uint8), normals=np.tile([0.0, 0.0, 1.0], (2, 1)),
        min_distance_m=np.ones(2), max_distance_m=np.full(2, 10.0),
    )  # fmt: skip
    return codec.encode_map_update(update)


def _keyframe(i: int) -> codec.KeyframeMessage:
    n = 4
    return codec.KeyframeMessage(
        id=i, stamp_ns=i * STEP_NS, frame_index=i, T_world_cam=_T(i), calibration=CAL, sensor="stereo",
        keypoints_px=np.zeros((n, 2), np.float32), levels=np.zeros(n, np.int16), angles_deg=np.zeros(n, np.float32),
        right_u=np.full(n, -1, np.float32), depth_m=np.full(n, -1, np.float32), descriptors=np.zeros((n, 32), np.uint8),
        map_point_ids=np.full(n, -1, np.int64), scale_factors=np.ones(1), new_point_ids=np.zeros(0, np.int64),
        new_points_world=np.zeros((0, 3)),
    )  # fmt: skip


def _write(path, streams: dict[str, list[tuple[str, bytes, int]]]):
    """streams: topic -> [(schema, data, log_time_ns)], written interleaved by log time as the recorder would."""
    items = sorted(((t, *m) for topic, ms in streams.items() for t in [topic] for m in ms), key=lambda x: x[3])
    with mcap_io.RecordingWriter(path) as writer:
        for topic, schema, data, log_time in items:
            writer.write(topic, schema, data, log_time)
    return path


def _run_streams(frames: int = 4) -> dict[str, list[tuple[str, bytes, int]]]:
    pose = [(codec.POSE_IN_FRAME, codec.encode_pose_in_frame(codec.StampedPose(i * STEP_NS, _T(i))), i * STEP_NS) for i in range(frames)]
    state = [(codec.TRACKING_STATE, _state(i), i * STEP_NS) for i in range(frames)]
    keyframes = [(codec.KEYFRAME, codec.encode_keyframe(_keyframe(i)), i * STEP_NS) for i in (0, 2)]
    updates = [(codec.MAP_UPDATE, _update(i), i * STEP_NS) for i in (0, 2)]
    end = (frames - 1) * STEP_NS
    state.append((codec.TRACKING_STATE, codec.encode_end_of_stream(codec.TRACKING_STATE, frames), end))
    keyframes.append((codec.KEYFRAME, codec.encode_end_of_stream(codec.KEYFRAME, 2), end))
    updates.append((codec.MAP_UPDATE, codec.encode_end_of_stream(codec.MAP_UPDATE, 2), end))
    return {replay.POSE_TOPIC: pose, replay.STATE_TOPIC: state, replay.KEYFRAME_TOPIC: keyframes, replay.MAP_UPDATE_TOPIC: updates}


def test_compared_topics_are_the_deterministic_ones():
    assert replay.COMPARED_TOPICS == ("/frontend/pose", "/frontend/state", "/frontend/keyframe", "/backend/map_update")


def test_measured_timings_are_not_compared():
    assert replay.message_difference(codec.TRACKING_STATE, _state(3, timings_ms=1.0), _state(3, timings_ms=7.5)) is None
    assert replay.message_difference(codec.TRACKING_STATE, _state(3), _state(3, n_tracked=99)) == ("n_tracked", "100", "99")


def test_field_path_reaches_into_repeated_sub_messages():
    a, b = _update(2), _update(2)
    changed = codec.decode_map_update(b)
    moved = dataclasses.replace(changed.keyframes[1], T_world_cam=_T(1) @ make_T(np.eye(3), np.array([1e-9, 0.0, 0.0])))
    b = codec.encode_map_update(dataclasses.replace(changed, keyframes=(changed.keyframes[0], moved, changed.keyframes[2])))
    path, _, _ = replay.message_difference(codec.MAP_UPDATE, a, b)
    assert path == "keyframes[1].T_world_cam.tx"


def test_array_bytes_differences_name_the_field_and_byte():
    p = np.arange(6, dtype=float).reshape(2, 3)
    q = p.copy()
    q[0, 1] += 1e-12  # the second float64: bytes 8..15
    path, recorded, replayed = replay.message_difference(codec.MAP_UPDATE, _update(0, p), _update(0, q))
    assert path.startswith("p_world (byte ") and 8 <= int(path.split()[-1].rstrip(")")) < 16
    assert recorded == replayed == "48 bytes"


def test_identical_recordings(tmp_path):
    a = _write(tmp_path / "a.mcap", _run_streams())
    b = _write(tmp_path / "b.mcap", _run_streams())
    comparison = replay.compare_recordings(a, b)
    assert comparison.identical and comparison.lines()[0] == "identical"
    assert comparison.counts == {
        replay.POSE_TOPIC: (4, 4), replay.STATE_TOPIC: (5, 5), replay.KEYFRAME_TOPIC: (3, 3), replay.MAP_UPDATE_TOPIC: (3, 3)
    }  # fmt: skip


def test_the_earliest_difference_by_stamp_is_reported(tmp_path):
    streams = _run_streams()
    a = _write(tmp_path / "a.mcap", streams)
    changed = dict(streams)
    changed[replay.STATE_TOPIC] = [*streams[replay.STATE_TOPIC]]
    changed[replay.STATE_TOPIC][3] = (codec.TRACKING_STATE, _state(3, n_tracked=7), 3 * STEP_NS)  # later
    changed[replay.MAP_UPDATE_TOPIC] = [*streams[replay.MAP_UPDATE_TOPIC]]
    changed[replay.MAP_UPDATE_TOPIC][1] = (codec.MAP_UPDATE, _update(2, np.zeros((2, 3))), 2 * STEP_NS)  # earlier
    comparison = replay.compare_recordings(a, _write(tmp_path / "b.mcap", changed))
    d = comparison.difference
    assert (d.topic, d.index, d.stamp_ns) == (replay.MAP_UPDATE_TOPIC, 1, 2 * STEP_NS)
    assert d.field.startswith("p_world (byte ") and 8 <= int(d.field.split()[-1].rstrip(")")) < 16  # p_world[0, 1]
    assert comparison.lines()[0].startswith("first difference: /backend/map_update message 1 (stamp_ns 200000000): p_world")


def test_a_missing_message_is_a_difference_with_counts(tmp_path):
    streams = _run_streams()
    a = _write(tmp_path / "a.mcap", streams)
    shorter = {**streams, replay.POSE_TOPIC: streams[replay.POSE_TOPIC][:3]}
    comparison = replay.compare_recordings(a, _write(tmp_path / "b.mcap", shorter))
    assert comparison.counts[replay.POSE_TOPIC] == (4, 3)
    d = comparison.difference
    assert (d.topic, d.index, d.field, d.expected, d.actual) == (replay.POSE_TOPIC, 3, "message", "a foxglove.PoseInFrame message", "none")


class _EchoBackend:
    """A stand-in backend whose update for keyframe i is _update(i), so the test controls what it says."""

    def __init__(self) -> None:
        self.processed = 0

    def step(self, keyframe: codec.KeyframeMessage) -> MapUpdate:
        self.processed += 1
        return codec.decode_map_update(_update(keyframe.id))


def test_backend_replay_compares_every_update_and_the_end_of_stream(tmp_path, monkeypatch):
    monkeypatch.setattr(BackendNode, "from_config", classmethod(lambda cls, config: _EchoBackend()))
    streams = _run_streams()
    comparison = replay.replay_backend(_write(tmp_path / "same.mcap", streams), BackendConfig())
    assert comparison.identical and comparison.counts == {replay.MAP_UPDATE_TOPIC: (3, 3)}
    changed = {**streams, replay.MAP_UPDATE_TOPIC: [*streams[replay.MAP_UPDATE_TOPIC]]}
    changed[replay.MAP_UPDATE_TOPIC][1] = (codec.MAP_UPDATE, _update(2, np.ones((2, 3))), 2 * STEP_NS)
    d = replay.replay_backend(_write(tmp_path / "changed.mcap", changed), BackendConfig()).difference
    assert (d.topic, d.index, d.stamp_ns) == (replay.MAP_UPDATE_TOPIC, 1, 2 * STEP_NS) and d.field.startswith("p_world")


def test_recorded_config_is_the_one_beside_the_recording(tmp_path):
    config = RunConfig(source=SourceConfig(spec="synthetic", max_frames=7))
    (tmp_path / "config.yaml").write_text(run_config_to_yaml(config))
    assert replay.recorded_run_config(tmp_path / "run.mcap") == config
    assert replay.recorded_run_config(tmp_path / "elsewhere" / "run.mcap") == RunConfig()


def test_replay_command_is_registered_and_runs_the_recording_in_lockstep(tmp_path):
    args = build_parser().parse_args(["replay", str(tmp_path / "run.mcap"), "--stage", "backend"])
    assert args.handler is replay_command.run and args.stage == "backend"
    (tmp_path / "config.yaml").write_text(run_config_to_yaml(RunConfig()))
    argv = replay_command.run_arguments(tmp_path / "run.mcap", tmp_path / "out", "r1", progress=False)
    assert argv[:4] == ["run", f"mcap:{(tmp_path / 'run.mcap').resolve()}", "--lockstep", "--no-faults"]
    assert argv[argv.index("--config") + 1] == str(tmp_path / "config.yaml") and "--no-progress" in argv


def test_replay_of_a_non_recording_fails_with_its_path(tmp_path, capsys):
    from zenslam.service.cli import main

    (tmp_path / "run.mcap").write_text("no")
    assert main(["replay", str(tmp_path / "run.mcap"), "--stage", "backend"]) == 2
    with pytest.raises(SystemExit):
        main(["replay", str(tmp_path / "run.mcap"), "--stage", "frontend"])
