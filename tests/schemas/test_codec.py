"""Every bus message survives encode -> decode, bad messages fail naming the field, and the _pb2 is fresh."""

from __future__ import annotations

import dataclasses
import importlib.util
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError
from zenslam.geometry import make_T, so3_exp
from zenslam.schemas import codec
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE, KeyframeCorrection, MapUpdate
from zenslam.service.sources.frame import SensorFrame

REPO_ROOT = Path(__file__).resolve().parents[2]
CAL = PinholeCalibration(fx=420.0, fy=421.5, cx=160.2, cy=120.7, width=32, height=24, baseline_m=0.12)


def _images(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    left = rng.integers(0, 256, (24, 32), dtype=np.uint8)
    right = rng.integers(0, 256, (24, 32), dtype=np.uint8)
    depth = rng.uniform(0.3, 9.0, (24, 32)).astype(np.float32)
    depth[0, :5] = 0.0  # unknown depth stays 0
    return left, right, depth


def test_stereo_frame_round_trip_is_exact():
    left, right, _ = _images(np.random.default_rng(1))
    frame = SensorFrame(index=7, stamp_ns=1_403_636_579_763_555_584, left=left, right=right)
    decoded = codec.decode_sensor_frame(codec.encode_sensor_frame(frame, CAL, "stereo", "kitti/06"))
    assert isinstance(decoded, codec.FrameMessage)
    assert decoded.frame.index == 7 and decoded.frame.stamp_ns == 1_403_636_579_763_555_584  # > 2^53: int64 exact
    np.testing.assert_array_equal(decoded.frame.left, left)
    np.testing.assert_array_equal(decoded.frame.right, right)
    assert decoded.frame.depth_m is None
    assert decoded.calibration == CAL
    assert decoded.sensor == "stereo" and decoded.source_name == "kitti/06"


def test_mono_calibration_without_baseline_survives():
    mono = PinholeCalibration(fx=300.0, fy=300.0, cx=16.0, cy=12.0, width=32, height=24)
    left, _, _ = _images(np.random.default_rng(2))
    decoded = codec.decode_sensor_frame(codec.encode_sensor_frame(SensorFrame(0, 5, left), mono, "mono"))
    assert decoded.calibration.baseline_m is None and decoded.sensor == "mono"
    assert decoded.frame.right is None


def test_depth_float32_is_exact_and_uint16_mm_within_half_a_millimetre():
    left, _, depth = _images(np.random.default_rng(3))
    frame = SensorFrame(1, 10, left, depth_m=depth)
    exact = codec.decode_sensor_frame(codec.encode_sensor_frame(frame, CAL, "rgbd"))
    np.testing.assert_array_equal(exact.frame.depth_m, depth)
    compact = codec.encode_sensor_frame(frame, CAL, "rgbd", depth_encoding="uint16_mm")
    assert len(compact) < len(codec.encode_sensor_frame(frame, CAL, "rgbd")) - 24 * 32  # 2 bytes per pixel saved
    mm = codec.decode_sensor_frame(compact).frame.depth_m
    assert mm.dtype == np.float32
    assert np.max(np.abs(mm - depth)) <= 0.0005 + 1e-6
    assert np.all(mm[0, :5] == 0.0)


def _textured(rng: np.random.Generator) -> np.ndarray:
    """A smooth ramp with noise: compressible like camera images, yet every pixel matters."""
    ramp = np.add.outer(np.arange(24), 3 * np.arange(32)).astype(np.int16)
    return np.clip(ramp + rng.integers(-3, 4, ramp.shape), 0, 255).astype(np.uint8)


def test_png_frames_decode_to_the_same_pixels_and_keep_everything_else():
    rng = np.random.default_rng(5)
    left, right, depth = _textured(rng), _textured(rng), _images(rng)[2]
    frame = SensorFrame(4, 1_000, left, right, depth_m=depth)
    raw = codec.encode_sensor_frame(frame, CAL, "rgbd", "tum/desk", depth_encoding="uint16_mm")
    for data in (codec.encode_sensor_frame(frame, CAL, "rgbd", "tum/desk", "uint16_mm", image_encoding="png"),
                 codec.sensor_frame_as_png(raw)):  # fmt: skip
        assert pb.SensorFrame.FromString(data).image_encoding == pb.IMAGE_ENCODING_PNG
        assert len(data) < len(raw) - 2 * 24 * 32 // 4  # the images shrink
        png, expected = codec.decode_sensor_frame(data), codec.decode_sensor_frame(raw)
        assert png.frame.left.dtype == np.uint8 and not png.frame.left.flags.writeable
        np.testing.assert_array_equal(png.frame.left, left)
        np.testing.assert_array_equal(png.frame.right, right)
        np.testing.assert_array_equal(png.frame.depth_m, expected.frame.depth_m)
        assert (png.frame.index, png.frame.stamp_ns, png.calibration, png.sensor, png.source_name) == (
            4, 1_000, CAL, "rgbd", "tum/desk"
        )
    as_png = codec.sensor_frame_as_png(raw)
    assert codec.sensor_frame_as_png(as_png) == as_png  # already PNG: unchanged
    end = codec.encode_end_of_stream(codec.SENSOR_FRAME, 3)
    assert codec.sensor_frame_as_png(end) == end


@pytest.mark.skipif(not hasattr(cv2, "IMWRITE_PNG_FILTER"), reason="this OpenCV has no IMWRITE_PNG_FILTER: libpng chooses each row's filter")
def test_pngs_filter_every_row_with_sub_and_decode_to_the_same_pixels():
    image = _textured(np.random.default_rng(7))
    data = codec.png_bytes(image)
    np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), image)
    # The image data: the IDAT chunks' deflate stream, one filter-type byte before each row (1: Sub).
    idat, at = b"", 8
    while at < len(data):
        length, kind = int.from_bytes(data[at : at + 4], "big"), data[at + 4 : at + 8]
        if kind == b"IDAT":
            idat += data[at + 8 : at + 8 + length]
        at += 12 + length
    rows = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(image.shape[0], image.shape[1] + 1)
    assert set(rows[:, 0].tolist()) == {1}


def test_a_png_of_the_wrong_size_names_the_frame():
    left = _textured(np.random.default_rng(6))
    msg = pb.SensorFrame.FromString(codec.encode_sensor_frame(SensorFrame(9, 0, left), CAL, "mono", image_encoding="png"))
    msg.left = codec.png_bytes(left[:, :30])
    with pytest.raises(codec.MessageError, match=r"sensor frame 9 left: the PNG holds uint8 \(24, 30\), expected uint8 \(24, 32\)"):
        codec.decode_sensor_frame(msg.SerializeToString())
    msg.left = b"not a png"
    with pytest.raises(codec.MessageError, match="sensor frame 9 left: the PNG holds undecodable bytes"):
        codec.decode_sensor_frame(msg.SerializeToString())


def test_image_size_must_match_calibration():
    left = np.zeros((24, 30), np.uint8)
    with pytest.raises(CalibrationError, match="30x24 but the calibration says 32x24"):
        codec.encode_sensor_frame(SensorFrame(0, 0, left), CAL, "mono")


def test_truncated_image_names_the_field():
    left, _, _ = _images(np.random.default_rng(4))
    msg = pb.SensorFrame.FromString(codec.encode_sensor_frame(SensorFrame(3, 0, left), CAL, "mono"))
    msg.left = msg.left[:-1]
    with pytest.raises(codec.MessageError, match="sensor frame 3 left: expected 768 bytes"):
        codec.decode_sensor_frame(msg.SerializeToString())


def test_garbage_is_a_message_error():
    with pytest.raises(codec.MessageError, match="cannot decode"):
        codec.decode_sensor_frame(b"\xff\xff\xff\xff")


@pytest.mark.parametrize(
    "schema, decode",
    [
        (codec.SENSOR_FRAME, codec.decode_sensor_frame),
        (codec.TRACKING_STATE, codec.decode_tracking_state),
        (codec.KEYFRAME, codec.decode_keyframe),
        (codec.MAP_UPDATE, codec.decode_map_update),
    ],
)
def test_end_of_stream_round_trip(schema, decode):
    assert decode(codec.encode_end_of_stream(schema, 42)) == codec.EndOfStream(42)


def test_status_streams_have_no_end_of_stream():
    with pytest.raises(codec.MessageError, match="no end-of-stream"):
        codec.encode_end_of_stream(codec.STAGE_STATUS, 1)


def test_tracking_state_round_trip():
    state = codec.TrackingStateMessage(
        index=12, stamp_ns=-5, state="lost", lost_reason="too few matches", n_tracked=9,
        timings_ms={"total": 30.5, "extraction": 12.25}, has_pose=False, keyframe_id=-1,
    )
    decoded = codec.decode_tracking_state(codec.encode_tracking_state(state))
    assert decoded == state
    ok = codec.TrackingStateMessage(index=0, stamp_ns=1, state="ok", has_pose=True, keyframe_id=3)
    assert codec.decode_tracking_state(codec.encode_tracking_state(ok)) == ok
    assert codec.decode_tracking_state(codec.encode_tracking_state(ok)).lost_reason is None


def test_tracking_state_carries_the_pose_relative_to_its_reference_keyframe():
    T = make_T(so3_exp(np.array([0.02, -0.1, 0.05])), np.array([0.3, 0.0, 1.2]))
    state = codec.TrackingStateMessage(0, 1, "ok", has_pose=True, reference_keyframe_id=0, T_reference_cam=T)
    decoded = codec.decode_tracking_state(codec.encode_tracking_state(state))
    assert decoded.reference_keyframe_id == 0  # keyframe 0 is a reference, not "unset"
    np.testing.assert_allclose(decoded.T_reference_cam, T, atol=1e-12)
    none = codec.decode_tracking_state(codec.encode_tracking_state(codec.TrackingStateMessage(1, 2, "lost")))
    assert none.reference_keyframe_id == -1 and none.T_reference_cam is None


def _keyframe(rng: np.random.Generator, n: int = 1000, m: int = 300) -> codec.KeyframeMessage:
    T = make_T(so3_exp(np.array([0.1, -0.4, 0.25])), np.array([1.0, -2.0, 0.5]))
    return codec.KeyframeMessage(
        id=4, stamp_ns=123_456_789_012, frame_index=40, T_world_cam=T, calibration=CAL, sensor="stereo",
        keypoints_px=(rng.uniform(0, 1, (n, 2)) * (CAL.width, CAL.height)).astype(np.float32),
        levels=rng.integers(0, 8, n).astype(np.int16),
        angles_deg=rng.uniform(0, 360, n).astype(np.float32),
        right_u=np.where(rng.random(n) < 0.5, -1.0, rng.uniform(0, 32, n)).astype(np.float32),
        depth_m=rng.uniform(0.5, 20, n).astype(np.float32),
        descriptors=rng.integers(0, 256, (n, 32), dtype=np.uint8),
        map_point_ids=np.where(rng.random(n) < 0.3, -1, rng.integers(0, 2**40, n)).astype(np.int64),
        scale_factors=1.2 ** np.arange(8),
        new_point_ids=rng.integers(0, 2**40, m).astype(np.int64),
        new_points_world=rng.normal(size=(m, 3)) * 10,
    )


def test_keyframe_round_trip():
    kf = _keyframe(np.random.default_rng(5))
    decoded = codec.decode_keyframe(codec.encode_keyframe(kf))
    for name in ("keypoints_px", "levels", "angles_deg", "right_u", "depth_m", "descriptors", "map_point_ids",
                 "scale_factors", "new_point_ids", "new_points_world"):
        got, want = getattr(decoded, name), getattr(kf, name)
        assert got.dtype == want.dtype and got.shape == want.shape, name
        np.testing.assert_array_equal(got, want, err_msg=name)
    # The pose travels as translation + quaternion: equal to 1e-12.
    np.testing.assert_allclose(decoded.T_world_cam, kf.T_world_cam, atol=1e-12)
    assert (decoded.id, decoded.stamp_ns, decoded.frame_index, decoded.sensor) == (4, 123_456_789_012, 40, "stereo")
    assert decoded.calibration == CAL


def test_keyframe_with_mismatched_arrays_is_refused():
    kf = _keyframe(np.random.default_rng(6), n=10, m=2)
    bad = codec.KeyframeMessage(**{**kf.__dict__, "levels": kf.levels[:9]})
    with pytest.raises(codec.MessageError, match="levels has 9 entries for 10 keypoints"):
        codec.encode_keyframe(bad)
    bad_desc = codec.KeyframeMessage(**{**kf.__dict__, "descriptors": np.zeros((10, 31), np.uint8)})
    with pytest.raises(codec.MessageError, match=r"descriptors must have shape \(N, 32\)"):
        codec.encode_keyframe(bad_desc)


def test_map_update_round_trip():
    rng = np.random.default_rng(8)
    p = 40
    update = MapUpdate(
        keyframe_id=9,
        stamp_ns=77,
        keyframes=tuple(
            KeyframeCorrection(k, make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3)), rng.integers(-1, 500, 20 + k))
            for k in (3, 5)
        ),
        point_ids=np.arange(p, dtype=np.int64) + BACKEND_POINT_ID_BASE,
        p_world=rng.normal(size=(p, 3)),
        descriptors=rng.integers(0, 256, (p, 32), dtype=np.uint8),
        normals=rng.normal(size=(p, 3)),
        min_distance_m=rng.uniform(0.5, 1, p),
        max_distance_m=rng.uniform(5, 10, p),
        removed_point_ids=np.array([1, 2, 3], np.int64),
        removed_keyframe_ids=np.array([4], np.int64),
    )
    decoded = codec.decode_map_update(codec.encode_map_update(update))
    assert (decoded.keyframe_id, decoded.stamp_ns) == (9, 77)
    assert [kf.id for kf in decoded.keyframes] == [3, 5]
    for got, want in zip(decoded.keyframes, update.keyframes):
        np.testing.assert_array_equal(got.map_point_ids, want.map_point_ids)
        np.testing.assert_allclose(got.T_world_cam, want.T_world_cam, atol=1e-12)
    for name in ("point_ids", "p_world", "descriptors", "removed_point_ids", "removed_keyframe_ids"):
        np.testing.assert_array_equal(getattr(decoded, name), getattr(update, name), err_msg=name)
    # Viewing directions and scale-invariance distances travel as float32, and decode as float64.
    for name in ("normals", "min_distance_m", "max_distance_m"):
        assert getattr(decoded, name).dtype == np.float64, name
        np.testing.assert_array_equal(getattr(decoded, name), getattr(update, name).astype(np.float32), err_msg=name)
    msg = pb.MapUpdate.FromString(codec.encode_map_update(update))
    for name in codec.ARRAY_FIELDS[codec.MAP_UPDATE]:
        if not getattr(msg, name):
            continue  # the float64 fields of older recordings
        want = getattr(update, name.removesuffix("_f32"))
        np.testing.assert_array_equal(codec.array_field(msg, name), want.astype(codec.array_field(msg, name).dtype), err_msg=name)
        assert codec.array_field(msg, name).dtype == (np.float32 if name.endswith("_f32") else np.asarray(want).dtype), name
    np.testing.assert_array_equal(codec.array_field(msg.keyframes[1], "map_point_ids"), update.keyframes[1].map_point_ids)
    empty = codec.decode_map_update(codec.encode_map_update(MapUpdate(keyframe_id=1, stamp_ns=2)))
    assert empty.keyframes == () and empty.p_world.shape == (0, 3) and empty.descriptors.shape == (0, 32)


def test_map_update_of_an_older_recording_decodes_its_float64_fields():
    """Recordings made before the float32 fields existed carry normals and distances as float64."""
    rng = np.random.default_rng(3)
    p = 5
    msg = pb.MapUpdate(keyframe_id=1, stamp_ns=2, num_points=p)
    msg.point_ids = np.arange(p, dtype="<i8").tobytes()
    msg.p_world = rng.normal(size=(p, 3)).astype("<f8").tobytes()
    msg.descriptors = rng.integers(0, 256, (p, 32), dtype=np.uint8).tobytes()
    normals, near = rng.normal(size=(p, 3)), rng.uniform(0.5, 1.0, p)
    msg.normals, msg.min_distance_m, msg.max_distance_m = normals.tobytes(), near.tobytes(), (near * 10).tobytes()
    decoded = codec.decode_map_update(msg.SerializeToString())
    np.testing.assert_array_equal(decoded.normals, normals)
    np.testing.assert_array_equal(decoded.min_distance_m, near)
    np.testing.assert_array_equal(decoded.max_distance_m, near * 10)


def test_array_field_reads_every_array_with_the_codecs_dtype_and_row_shape():
    kf = _keyframe(np.random.default_rng(9), n=12, m=5)
    msg = pb.Keyframe.FromString(codec.encode_keyframe(kf))
    for name in codec.ARRAY_FIELDS[codec.KEYFRAME]:
        got, want = codec.array_field(msg, name), getattr(kf, name)
        assert got.dtype == want.dtype and got.shape == want.shape, name
        np.testing.assert_array_equal(got, want, err_msg=name)
    T = np.stack([make_T(so3_exp(np.array([0.0, 0.1 * k, 0.0])), np.array([k, 0.0, 0.0])) for k in range(3)])
    trajectory = codec.KeyframeTrajectoryMessage(np.arange(3, dtype=np.int64), np.arange(3, dtype=np.int64) * 10, T)
    snapshot = pb.MapSnapshot.FromString(
        codec.encode_map_snapshot(codec.MapSnapshotMessage(trajectory, np.array([7, 8], np.int64), np.ones((2, 3))))
    )
    np.testing.assert_array_equal(codec.array_field(snapshot.keyframes, "T_world_cam"), T)
    np.testing.assert_array_equal(codec.array_field(snapshot, "p_world"), np.ones((2, 3)))


def test_every_bytes_field_of_the_compared_messages_has_an_array_layout():
    for schema in (codec.KEYFRAME, codec.MAP_UPDATE, codec.KEYFRAME_TRAJECTORY, codec.MAP_SNAPSHOT):
        descriptors = [codec.MESSAGE_CLASSES[schema].DESCRIPTOR]
        descriptors += [f.message_type for f in descriptors[0].fields if f.message_type is not None]
        for descriptor in descriptors:
            for f in descriptor.fields:
                if f.type == f.TYPE_BYTES:
                    assert f.name in codec.ARRAY_FIELDS[descriptor.full_name], f"{descriptor.full_name}.{f.name}"


def test_array_field_falls_back_to_bytes_for_unlisted_or_ragged_fields():
    msg = pb.MapUpdate(p_world=bytes(range(20)))  # not a whole number of float64 triples
    np.testing.assert_array_equal(codec.array_field(msg, "p_world"), np.arange(20, dtype=np.uint8))
    frame = pb.SensorFrame(left=b"\x01\x02")
    assert codec.array_field(frame, "left").tolist() == [1, 2]

def test_pose_in_frame_is_foxglove_and_round_trips():
    T = make_T(so3_exp(np.array([0.3, 0.2, -1.1])), np.array([5.0, 0.25, -3.0]))
    data = codec.encode_pose_in_frame(codec.StampedPose(1_700_000_000_123_456_789, T))
    raw = PoseInFrame.FromString(data)
    assert raw.frame_id == "world"
    assert (raw.timestamp.seconds, raw.timestamp.nanos) == (1_700_000_000, 123_456_789)
    assert raw.pose.orientation.w > 0  # x, y, z, w order filled as Foxglove expects
    decoded = codec.decode_pose_in_frame(data)
    assert decoded.stamp_ns == 1_700_000_000_123_456_789
    np.testing.assert_allclose(decoded.T_world_cam, T, atol=1e-12)


def test_stage_status_round_trip():
    status = codec.StageStatusMessage("frontend", "running", processed=10, step_ms=33.5, queue_depth=2, dropped=1, detail="x")
    assert codec.decode_stage_status(codec.encode_stage_status(status)) == status
    source = codec.StageStatusMessage("source", "finished", processed=50, skipped={"stamp_repeat": 2, "corrupt": 1})
    assert codec.decode_stage_status(codec.encode_stage_status(source)) == source
    # Nothing skipped adds no bytes: statuses of clean runs are what they were before the field existed.
    plain = codec.StageStatusMessage("source", "finished", processed=50)
    assert codec.encode_stage_status(plain) == codec.encode_stage_status(codec.StageStatusMessage("source", "finished", 50, skipped={}))
    assert len(codec.encode_stage_status(plain)) < len(codec.encode_stage_status(source))


def test_keyframe_of_1000_keypoints_is_compact():
    """bytes fields: about 60 KB for 1,000 keypoints (no per-element framing)."""
    size = len(codec.encode_keyframe(_keyframe(np.random.default_rng(7), n=1000, m=0)))
    per_keypoint = 2 * 4 + 2 + 4 + 4 + 4 + 32 + 8
    assert 1000 * per_keypoint <= size <= 1000 * per_keypoint + 400


def test_schema_names_are_the_protobuf_full_names():
    for name, cls in codec.MESSAGE_CLASSES.items():
        assert cls.DESCRIPTOR.full_name == name


@pytest.mark.skipif(importlib.util.find_spec("grpc_tools") is None, reason="grpcio-tools (dev extra) is not installed")
def test_generated_code_matches_the_proto():
    result = subprocess.run(
        [sys.executable, str(REPO_ROOT / "scripts" / "generate_schemas.py"), "--check"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_loop_messages_round_trip_accepted_and_rejected():
    from zenslam.geometry import make_T, so3_exp

    T_a = make_T(so3_exp(np.array([0.1, -0.2, 0.3])), np.array([1.0, 2.0, 3.0]))
    T_b = make_T(so3_exp(np.array([0.0, 0.5, 0.0])), np.array([-1.0, 0.0, 4.0]))
    accepted = codec.LoopMessage(
        keyframe_id=40, stamp_ns=4_000, loop_keyframe_id=3, loop_stamp_ns=300, accepted=True, reason="",
        T_world_cur_before=T_a, T_world_loop=T_b, T_cur_loop=T_b, scale=1.0, inliers=87, T_world_cur_after=T_a,
    )
    back = codec.decode_loop(codec.encode_loop(accepted))
    assert (back.keyframe_id, back.loop_keyframe_id, back.loop_stamp_ns, back.accepted, back.inliers) == (40, 3, 300, True, 87)
    np.testing.assert_allclose(back.T_cur_loop, T_b, atol=1e-12)
    np.testing.assert_allclose(back.T_world_cur_after, T_a, atol=1e-12)
    failed = dataclasses.replace(accepted, accepted=False, reason="12 BoW matches < 20", inliers=0)
    rejected = codec.decode_loop(codec.encode_loop(failed))
    assert not rejected.accepted and rejected.reason == "12 BoW matches < 20"
    np.testing.assert_allclose(rejected.T_cur_loop, np.eye(4))
    # refused after verification: the transform it asked for goes along, the pose after does not
    refused = codec.decode_loop(codec.encode_loop(dataclasses.replace(accepted, accepted=False, reason="drift budget", scale=1.3)))
    assert (refused.accepted, refused.inliers, refused.scale) == (False, 87, 1.3)
    np.testing.assert_allclose(refused.T_cur_loop, T_b, atol=1e-12)
    np.testing.assert_allclose(refused.T_world_cur_after, np.eye(4))


def test_map_update_carries_the_corrections_that_follow_it():
    update = codec.decode_map_update(codec.encode_map_update(MapUpdate(keyframe_id=5, stamp_ns=9, corrections_following=1)))
    assert update.corrections_following == 1 and update.answers_keyframe
    assert codec.decode_map_update(codec.encode_map_update(MapUpdate(keyframe_id=5, stamp_ns=9))).corrections_following == 0
    early = codec.decode_map_update(codec.encode_map_update(MapUpdate(keyframe_id=5, stamp_ns=9, corrections_following=1, corrections_after_next_frame=True)))
    assert early.corrections_after_next_frame and early.corrections_following == 1
    assert not codec.decode_map_update(codec.encode_map_update(MapUpdate(keyframe_id=5, stamp_ns=9))).corrections_after_next_frame


def test_keyframe_trajectory_round_trips_its_culled_keyframes():
    T = np.stack([make_T(so3_exp(np.array([0.0, 0.1 * k, 0.0])), np.array([k, 0.0, 0.0])) for k in range(3)])
    sent = codec.KeyframeTrajectoryMessage(
        np.array([0], np.int64), np.array([5], np.int64), T[:1], keyframes_processed=4, finished=True,
        culled_keyframe_ids=np.array([2, 3], np.int64), culled_stamps_ns=np.array([20, 30], np.int64), culled_T_world_cam=T[1:],
    )  # fmt: skip
    got = codec.decode_keyframe_trajectory(codec.encode_keyframe_trajectory(sent))
    np.testing.assert_array_equal(got.culled_keyframe_ids, [2, 3])
    np.testing.assert_array_equal(got.culled_stamps_ns, [20, 30])
    np.testing.assert_array_equal(got.culled_T_world_cam, T[1:])
    plain = codec.decode_keyframe_trajectory(codec.encode_keyframe_trajectory(codec.KeyframeTrajectoryMessage(sent.keyframe_ids, sent.stamps_ns, T[:1])))
    assert plain.culled_keyframe_ids.shape == (0,) and plain.culled_T_world_cam.shape == (0, 4, 4)


@pytest.mark.parametrize(
    ("field", "value", "problem"),
    [
        ("levels", lambda kf: np.full_like(kf.levels, 9), "keypoint levels span"),
        ("keypoints_px", lambda kf: kf.keypoints_px + np.float32(100.0), "outside the 32x24 image"),
        ("new_points_world", lambda kf: np.full_like(kf.new_points_world, np.nan), "new_points_world holds non-finite"),
        ("new_point_ids", lambda kf: np.zeros_like(kf.new_point_ids), "new_point_ids repeats an id"),
        ("map_point_ids", lambda kf: np.full_like(kf.map_point_ids, -5), "ids are >= -1"),
        ("scale_factors", lambda kf: kf.scale_factors[::-1].copy(), "scale_factors must start at 1 and increase"),
    ],
)
def test_keyframe_values_that_no_frontend_sends_are_refused_on_decoding(field, value, problem):
    kf = _keyframe(np.random.default_rng(7), n=50, m=10)
    data = codec.encode_keyframe(codec.KeyframeMessage(**{**kf.__dict__, field: value(kf)}))
    with pytest.raises(codec.MessageError, match=problem):
        codec.decode_keyframe(data)
