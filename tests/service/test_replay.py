"""Replay comparisons: paths and values of differences (down to array elements), tolerance, ignored timings,
counts, the earliest difference, backend replay, the command line."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.geometry import make_T, so3_exp
from zenslam.backend.node import StepOutput
from zenslam.schemas import codec
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.service import backend_replay, mcap_io, replay
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
    assert replay.COMPARED_TOPICS == ("/frontend/pose", "/frontend/state", "/frontend/keyframe", "/backend/map_update", "/backend/loop")


def _difference(schema: str, a: bytes, b: bytes, tolerance: float | None = None) -> tuple[str, str, str] | None:
    found = replay.compare_encoded(schema, a, b, tolerance).difference
    return None if found is None else (found.path, found.recorded, found.replayed)


def _update_with(**changes) -> bytes:
    update = codec.decode_map_update(_update(1))
    return codec.encode_map_update(dataclasses.replace(update, **changes))


def test_measured_timings_are_not_compared():
    assert _difference(codec.TRACKING_STATE, _state(3, timings_ms=1.0), _state(3, timings_ms=7.5)) is None
    assert _difference(codec.TRACKING_STATE, _state(3), _state(3, n_tracked=99)) == ("n_tracked", "100", "99")


def test_field_path_reaches_into_repeated_sub_messages():
    a, b = _update(2), _update(2)
    changed = codec.decode_map_update(b)
    moved = dataclasses.replace(changed.keyframes[1], T_world_cam=_T(1) @ make_T(np.eye(3), np.array([1e-9, 0.0, 0.0])))
    b = codec.encode_map_update(dataclasses.replace(changed, keyframes=(changed.keyframes[0], moved, changed.keyframes[2])))
    path, recorded, replayed = _difference(codec.MAP_UPDATE, a, b)
    assert path == "keyframes[1].T_world_cam.tx" and float(replayed) - float(recorded) == pytest.approx(1e-9, rel=1e-3)


def test_an_array_difference_names_the_element_and_both_values():
    p = np.arange(6, dtype=float).reshape(2, 3)
    q = p.copy()
    q[1, 2] += 1e-12
    assert _difference(codec.MAP_UPDATE, _update(0, p), _update(0, q)) == ("p_world[1][2]", "5.0", "5.000000000001")


def test_integer_float32_and_matrix_arrays_are_decoded_with_their_dtype_and_shape():
    assert _difference(codec.MAP_UPDATE, _update(1), _update_with(point_ids=np.array([1, 3], np.int64))) == ("point_ids[1]", "2", "3")
    kf = _keyframe(2)
    moved = kf.keypoints_px.copy()
    moved[3, 1] = 0.1
    a, b = codec.encode_keyframe(kf), codec.encode_keyframe(dataclasses.replace(kf, keypoints_px=moved))
    assert _difference(codec.KEYFRAME, a, b) == ("keypoints_px[3][1]", "0.0", "0.1")  # float32 shown with its own digits
    T = np.stack([_T(0), _T(1)])
    U = T.copy()
    U[1, 2, 3] = 7.0
    trajectory = [codec.encode_keyframe_trajectory(codec.KeyframeTrajectoryMessage(np.arange(2), np.arange(2), M)) for M in (T, U)]
    assert _difference(codec.KEYFRAME_TRAJECTORY, *trajectory) == ("T_world_cam[1][2][3]", "0.0", "7.0")


def test_an_element_only_one_side_has_is_absent_never_a_size():
    a = _update_with(removed_point_ids=np.array([4, 5], np.int64))
    b = _update_with(removed_point_ids=np.array([4, 5, 6], np.int64))
    assert _difference(codec.MAP_UPDATE, a, b) == ("removed_point_ids[2]", "absent", "6")
    assert _difference(codec.MAP_UPDATE, b, a) == ("removed_point_ids[2]", "6", "absent")
    longer = codec.decode_map_update(_update(2))
    path, recorded, replayed = _difference(codec.MAP_UPDATE, _update(1), _update_with(keyframes=longer.keyframes))
    assert (path, recorded, replayed) == ("keyframes[2]", "absent", "a KeyframeCorrection")


def test_enum_values_are_named():
    lost = codec.encode_tracking_state(codec.TrackingStateMessage(3, 3 * STEP_NS, "lost", has_pose=True))
    ok = codec.encode_tracking_state(codec.TrackingStateMessage(3, 3 * STEP_NS, "ok", has_pose=True))
    assert _difference(codec.TRACKING_STATE, ok, lost) == ("state", "TRACKING_STATE_OK", "TRACKING_STATE_LOST")


def test_bit_exact_comparison_tells_signed_zeros_apart_and_matches_nans():
    zero, negative_zero, nan = np.zeros((2, 3)), np.zeros((2, 3)), np.full((2, 3), np.nan)
    negative_zero[0, 2] = -0.0
    assert _difference(codec.MAP_UPDATE, _update(0, zero), _update(0, negative_zero)) == ("p_world[0][2]", "0.0", "-0.0")
    assert _difference(codec.MAP_UPDATE, _update(0, nan), _update(0, nan.copy())) is None


def test_tolerance_is_absolute_up_to_magnitude_one_and_relative_above():
    base = np.array([[1e-3, 1000.0, 0.5], [2.0, -3.0, 4.0]])

    def moved(i: int, j: int, delta: float) -> bytes:
        q = base.copy()
        q[i, j] += delta
        return _update(0, q)

    recorded = _update(0, base)
    assert _difference(codec.MAP_UPDATE, recorded, moved(0, 1, 5e-4), tolerance=1e-6) is None  # 5e-7 of 1000
    assert _difference(codec.MAP_UPDATE, recorded, moved(0, 1, 5e-3), tolerance=1e-6)[0] == "p_world[0][1]"  # 5e-6 of 1000
    assert _difference(codec.MAP_UPDATE, recorded, moved(0, 0, 9e-7), tolerance=1e-6) is None  # 9e-7 absolute
    assert _difference(codec.MAP_UPDATE, recorded, moved(0, 0, 2e-6), tolerance=1e-6)[0] == "p_world[0][0]"  # 2e-6 absolute
    nan = base.copy()
    nan[1, 0] = np.nan
    assert _difference(codec.MAP_UPDATE, recorded, _update(0, nan), tolerance=1.0)[0] == "p_world[1][0]"
    within = replay.compare_encoded(codec.MAP_UPDATE, recorded, moved(1, 2, 2e-9), tolerance=1e-6).largest
    assert within.difference.path == "p_world[1][2]" and within.scaled == pytest.approx(2e-9 / 4.0, rel=1e-6)


def test_tolerance_never_forgives_integers_or_ids():
    other_ids = _update_with(point_ids=np.array([1, 3], np.int64))
    assert _difference(codec.MAP_UPDATE, _update(1), other_ids, tolerance=10.0) == ("point_ids[1]", "2", "3")
    assert _difference(codec.TRACKING_STATE, _state(3), _state(3, n_tracked=99), tolerance=10.0) == ("n_tracked", "100", "99")


def test_scalar_fields_take_the_tolerance_too():
    a, b = _update(2), codec.decode_map_update(_update(2))
    moved = dataclasses.replace(b.keyframes[1], T_world_cam=_T(1) @ make_T(np.eye(3), np.array([1e-9, 0.0, 0.0])))
    b = codec.encode_map_update(dataclasses.replace(b, keyframes=(b.keyframes[0], moved, b.keyframes[2])))
    comparison = replay.compare_encoded(codec.MAP_UPDATE, a, b, tolerance=1e-8)
    assert comparison.difference is None and comparison.largest.difference.path == "keyframes[1].T_world_cam.tx"


def test_undecodable_messages_are_compared_byte_by_byte():
    found = replay.compare_encoded("unknown.Schema", b"\x01\x02\x03", b"\x01\x07\x03").difference
    assert (found.path, found.recorded, found.replayed) == ("bytes[1]", "2", "7")


def test_identical_recordings(tmp_path):
    a = _write(tmp_path / "a.mcap", _run_streams())
    b = _write(tmp_path / "b.mcap", _run_streams())
    comparison = replay.compare_recordings(a, b)
    assert comparison.identical and comparison.lines()[0] == "identical"
    assert comparison.counts == {
        replay.POSE_TOPIC: (4, 4), replay.STATE_TOPIC: (5, 5), replay.KEYFRAME_TOPIC: (3, 3), replay.MAP_UPDATE_TOPIC: (3, 3),
        replay.LOOP_TOPIC: (0, 0),
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
    assert (d.field, d.expected, d.actual) == ("p_world[0][1]", "1.0", "0.0")
    assert comparison.lines()[0] == (
        "first difference: /backend/map_update message 1 (stamp_ns 200000000): p_world[0][1]: recorded 1.0, replayed 0.0"
    )


def test_recordings_equivalent_within_a_tolerance_report_the_largest_deviation(tmp_path):
    streams = _run_streams()
    a = _write(tmp_path / "a.mcap", streams)
    nudged = np.arange(6, dtype=float).reshape(2, 3)
    nudged[1, 1] += 4e-9  # 1e-9 of 4.0
    changed = {**streams, replay.MAP_UPDATE_TOPIC: [*streams[replay.MAP_UPDATE_TOPIC]]}
    changed[replay.MAP_UPDATE_TOPIC][1] = (codec.MAP_UPDATE, _update(2, nudged), 2 * STEP_NS)
    b = _write(tmp_path / "b.mcap", changed)
    exact = replay.compare_recordings(a, b)
    assert not exact.equivalent and exact.lines()[0].startswith("first difference: /backend/map_update message 1")
    within = replay.compare_recordings(a, b, tolerance=1e-6)
    assert within.equivalent and not within.identical
    assert within.lines()[0] == (
        "equivalent within 1e-06: largest deviation 1e-09 at /backend/map_update message 1 (stamp_ns 200000000): "
        "p_world[1][1]: recorded 4.0, replayed 4.000000004"
    )
    beyond = replay.compare_recordings(a, b, tolerance=1e-10)
    assert not beyond.equivalent and beyond.lines()[0].startswith("first difference beyond 1e-10: /backend/map_update message 1")
    assert replay.compare_recordings(a, a, tolerance=1e-6).lines()[0] == "identical"


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

    def step(self, keyframe: codec.KeyframeMessage) -> StepOutput:
        self.processed += 1
        return StepOutput([codec.decode_map_update(_update(keyframe.id))])


def test_backend_replay_compares_every_update_and_the_end_of_stream(tmp_path):
    streams = _run_streams()
    recording = _write(tmp_path / "same.mcap", streams)
    keyframes = replay.read_topics(recording, (replay.KEYFRAME_TOPIC,))[replay.KEYFRAME_TOPIC]
    replayed = backend_replay.map_updates(keyframes, _EchoBackend())
    assert [m.log_time_ns for m in replayed] == [0, 2 * STEP_NS, 2 * STEP_NS]  # the end of stream at the last stamp
    recorded = replay.read_topics(recording, (replay.MAP_UPDATE_TOPIC,))[replay.MAP_UPDATE_TOPIC]
    comparison = replay.compare_streams(replay.MAP_UPDATE_TOPIC, recorded, replayed)
    assert comparison.identical and comparison.counts == {replay.MAP_UPDATE_TOPIC: (3, 3)}
    changed = [*recorded]
    changed[1] = dataclasses.replace(changed[1], data=_update(2, np.ones((2, 3))))
    d = replay.compare_streams(replay.MAP_UPDATE_TOPIC, changed, replayed).difference
    assert (d.topic, d.index, d.stamp_ns, d.field) == (replay.MAP_UPDATE_TOPIC, 1, 2 * STEP_NS, "p_world[0][0]")


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
    assert "--save-map" not in argv


def test_a_replay_saves_its_map_in_its_own_run_folder(tmp_path):
    """A run that saved its map is replayed with the map written beside the replay, not over the original."""
    import dataclasses

    config = RunConfig()
    config = dataclasses.replace(config, backend=dataclasses.replace(config.backend, save_map=str(tmp_path / "maps" / "room.zmap")))
    (tmp_path / "config.yaml").write_text(run_config_to_yaml(config))
    argv = replay_command.run_arguments(tmp_path / "run.mcap", tmp_path / "out", "r1", progress=False)
    assert argv[argv.index("--save-map") + 1] == str(tmp_path / "out" / "r1" / "room.zmap")


def test_replay_of_a_non_recording_fails_with_its_path(tmp_path, capsys):
    from zenslam.service.cli import main

    (tmp_path / "run.mcap").write_text("no")
    assert main(["replay", str(tmp_path / "run.mcap"), "--stage", "backend"]) == 2
    with pytest.raises(SystemExit):
        main(["replay", str(tmp_path / "run.mcap"), "--stage", "frontend"])


def test_replay_help_names_the_real_arguments_and_defines_the_tolerance(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["replay", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for argument in ("recording", "--stage {all,backend}", "--tolerance X", "--output OUTPUT", "--run-id RUN_ID", "--no-progress"):
        assert argument in text
    assert "|r - p| <= X * max(1, |r|)" in text and "exit status: 0 identical or equivalent, 1 a difference" in text


def test_tolerance_must_be_a_finite_non_negative_number(tmp_path):
    args = build_parser().parse_args(["replay", str(tmp_path / "run.mcap"), "--tolerance", "1e-9"])
    assert args.tolerance == 1e-9 and build_parser().parse_args(["replay", "x.mcap"]).tolerance is None
    for bad in ("-1", "nan", "inf", "tiny"):
        with pytest.raises(SystemExit):
            build_parser().parse_args(["replay", "x.mcap", "--tolerance", bad])
