"""Keyframes (frontend/keyframe): pose, keypoints with their descriptors and map points, new map points."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import MessageError
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.codec.end_of_stream import EndOfStream
from zenslam.schemas.codec.packing import (
    SENSOR_CODES,
    calibration_from_pb,
    calibration_to_pb,
    pack,
    parse,
    sensor_from_pb,
    transform_from_pb,
    transform_to_pb,
    unpack,
)
from zenslam.schemas.message_checks import check_keyframe_values


@dataclass(frozen=True)
class KeyframeMessage:
    """A keyframe on frontend/keyframe: N keypoints, M new map points, L pyramid levels."""

    id: int
    stamp_ns: int
    frame_index: int
    T_world_cam: np.ndarray  # (4, 4)
    calibration: PinholeCalibration
    sensor: SensorKind
    keypoints_px: np.ndarray  # (N, 2) float32, level-0 pixels
    levels: np.ndarray  # (N,) int16
    angles_deg: np.ndarray  # (N,) float32
    right_u: np.ndarray  # (N,) float32 pixels, -1 if none
    depth_m: np.ndarray  # (N,) float32 metres, -1 if none
    descriptors: np.ndarray  # (N, 32) uint8
    map_point_ids: np.ndarray  # (N,) int64, -1 if none
    scale_factors: np.ndarray  # (L,) float64
    new_point_ids: np.ndarray  # (M,) int64
    new_points_world: np.ndarray  # (M, 3) float64 metres


def encode_keyframe(kf: KeyframeMessage) -> bytes:
    """Encode a frontend/keyframe message; array shapes must agree with the keypoint count."""
    n = len(kf.keypoints_px)
    m = len(kf.new_point_ids)
    msg = pb.Keyframe(id=kf.id, stamp_ns=kf.stamp_ns, frame_index=kf.frame_index, num_keypoints=n, num_new_points=m)
    transform_to_pb(kf.T_world_cam, msg.T_world_cam)
    calibration_to_pb(kf.calibration, msg.calibration)
    msg.sensor = SENSOR_CODES[kf.sensor]
    per_keypoint = {
        "levels": (kf.levels, "<i2", ()),
        "angles_deg": (kf.angles_deg, "<f4", ()),
        "right_u": (kf.right_u, "<f4", ()),
        "depth_m": (kf.depth_m, "<f4", ()),
        "descriptors": (kf.descriptors, "u1", (32,)),
        "map_point_ids": (kf.map_point_ids, "<i8", ()),
    }
    msg.keypoints_px = pack(kf.keypoints_px, "<f4", (2,), f"keyframe {kf.id} keypoints_px")
    for name, (array, dtype, tail) in per_keypoint.items():
        if len(array) != n:
            raise MessageError(f"keyframe {kf.id}: {name} has {len(array)} entries for {n} keypoints")
        setattr(msg, name, pack(array, dtype, tail, f"keyframe {kf.id} {name}"))
    if len(kf.new_points_world) != m:
        raise MessageError(f"keyframe {kf.id}: {len(kf.new_points_world)} new point positions for {m} new point ids")
    msg.new_point_ids = pack(kf.new_point_ids, "<i8", (), f"keyframe {kf.id} new_point_ids")
    msg.new_points_world = pack(kf.new_points_world, "<f8", (3,), f"keyframe {kf.id} new_points_world")
    msg.scale_factors = pack(kf.scale_factors, "<f8", (), f"keyframe {kf.id} scale_factors")
    return msg.SerializeToString()


def decode_keyframe(data: bytes) -> KeyframeMessage | EndOfStream:
    """Decode a frontend/keyframe message."""
    msg = parse(pb.Keyframe, data)
    if msg.end_of_stream:
        return EndOfStream(msg.count)
    n, m, where = msg.num_keypoints, msg.num_new_points, f"keyframe {msg.id}"
    keyframe = KeyframeMessage(
        id=msg.id,
        stamp_ns=msg.stamp_ns,
        frame_index=msg.frame_index,
        T_world_cam=transform_from_pb(msg.T_world_cam),
        calibration=calibration_from_pb(msg.calibration, where),
        sensor=sensor_from_pb(msg.sensor, where),
        keypoints_px=unpack(msg.keypoints_px, "<f4", (n, 2), f"{where} keypoints_px"),
        levels=unpack(msg.levels, "<i2", (n,), f"{where} levels"),
        angles_deg=unpack(msg.angles_deg, "<f4", (n,), f"{where} angles_deg"),
        right_u=unpack(msg.right_u, "<f4", (n,), f"{where} right_u"),
        depth_m=unpack(msg.depth_m, "<f4", (n,), f"{where} depth_m"),
        descriptors=unpack(msg.descriptors, "u1", (n, 32), f"{where} descriptors"),
        map_point_ids=unpack(msg.map_point_ids, "<i8", (n,), f"{where} map_point_ids"),
        scale_factors=unpack(msg.scale_factors, "<f8", (len(msg.scale_factors) // 8,), f"{where} scale_factors"),
        new_point_ids=unpack(msg.new_point_ids, "<i8", (m,), f"{where} new_point_ids"),
        new_points_world=unpack(msg.new_points_world, "<f8", (m, 3), f"{where} new_points_world"),
    )
    k = keyframe
    check_keyframe_values(
        k.id, k.T_world_cam, k.calibration.width, k.calibration.height, k.keypoints_px, k.levels, k.angles_deg,
        k.right_u, k.depth_m, k.map_point_ids, k.scale_factors, k.new_point_ids, k.new_points_world,
    )
    return keyframe
