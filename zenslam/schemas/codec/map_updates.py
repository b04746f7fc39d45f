"""Map updates (backend/map_update): corrected keyframe poses and associations, points changed and removed."""

from __future__ import annotations

import numpy as np

from zenslam.errors import MessageError
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.codec.end_of_stream import EndOfStream
from zenslam.schemas.codec.packing import pack, parse, transform_from_pb, transform_to_pb, unpack
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.schemas.message_checks import check_map_update_values

_MAP_UPDATE_KIND_TO_PB = {"keyframe": pb.MAP_UPDATE_KIND_KEYFRAME, "correction": pb.MAP_UPDATE_KIND_CORRECTION}
# Recordings made before update kinds existed carry none: each of their updates answered a keyframe.
_MAP_UPDATE_KIND_FROM_PB = {pb.MAP_UPDATE_KIND_UNSPECIFIED: "keyframe", **{v: k for k, v in _MAP_UPDATE_KIND_TO_PB.items()}}


def encode_map_update(update: MapUpdate) -> bytes:
    """Encode a backend/map_update message."""
    msg = pb.MapUpdate(
        keyframe_id=update.keyframe_id, stamp_ns=update.stamp_ns, num_points=len(update.point_ids),
        kind=_MAP_UPDATE_KIND_TO_PB[update.kind], corrections_following=update.corrections_following,
        corrections_after_next_frame=update.corrections_after_next_frame,
    )
    for kf in update.keyframes:
        correction = msg.keyframes.add(id=kf.id, num_keypoints=len(kf.map_point_ids))
        transform_to_pb(kf.T_world_cam, correction.T_world_cam)
        correction.map_point_ids = pack(kf.map_point_ids, "<i8", (), f"map update keyframe {kf.id} map_point_ids")
    where = f"map update of keyframe {update.keyframe_id}"
    msg.point_ids = pack(update.point_ids, "<i8", (), f"{where} point_ids")
    msg.p_world = pack(update.p_world, "<f8", (3,), f"{where} p_world")
    msg.descriptors = pack(update.descriptors, "u1", (32,), f"{where} descriptors")
    msg.normals_f32 = pack(update.normals, "<f4", (3,), f"{where} normals")
    msg.min_distance_m_f32 = pack(update.min_distance_m, "<f4", (), f"{where} min_distance_m")
    msg.max_distance_m_f32 = pack(update.max_distance_m, "<f4", (), f"{where} max_distance_m")
    msg.removed_point_ids = pack(update.removed_point_ids, "<i8", (), f"{where} removed_point_ids")
    msg.removed_keyframe_ids = pack(update.removed_keyframe_ids, "<i8", (), f"{where} removed_keyframe_ids")
    return msg.SerializeToString()


def decode_map_update(data: bytes) -> MapUpdate | EndOfStream:
    """Decode a backend/map_update message."""
    msg = parse(pb.MapUpdate, data)
    if msg.end_of_stream:
        return EndOfStream(msg.count)
    p, where = msg.num_points, f"map update of keyframe {msg.keyframe_id}"
    keyframes = tuple(
        KeyframeCorrection(
            id=kf.id,
            T_world_cam=transform_from_pb(kf.T_world_cam),
            map_point_ids=unpack(kf.map_point_ids, "<i8", (kf.num_keypoints,), f"{where} keyframe {kf.id} map_point_ids"),
        )
        for kf in msg.keyframes
    )
    if msg.kind not in _MAP_UPDATE_KIND_FROM_PB:
        raise MessageError(f"{where}: update kind {msg.kind} is unknown; the sender's zenslam is newer than this one")
    update = MapUpdate(
        kind=_MAP_UPDATE_KIND_FROM_PB[msg.kind],
        corrections_following=msg.corrections_following,
        corrections_after_next_frame=msg.corrections_after_next_frame,
        keyframe_id=msg.keyframe_id,
        stamp_ns=msg.stamp_ns,
        keyframes=keyframes,
        point_ids=unpack(msg.point_ids, "<i8", (p,), f"{where} point_ids"),
        p_world=unpack(msg.p_world, "<f8", (p, 3), f"{where} p_world"),
        descriptors=unpack(msg.descriptors, "u1", (p, 32), f"{where} descriptors"),
        normals=_unpack_float(msg, "normals", (p, 3), where),
        min_distance_m=_unpack_float(msg, "min_distance_m", (p,), where),
        max_distance_m=_unpack_float(msg, "max_distance_m", (p,), where),
        removed_point_ids=unpack(msg.removed_point_ids, "<i8", (len(msg.removed_point_ids) // 8,), f"{where} removed_point_ids"),
        removed_keyframe_ids=unpack(
            msg.removed_keyframe_ids, "<i8", (len(msg.removed_keyframe_ids) // 8,), f"{where} removed_keyframe_ids"
        ),
    )
    u = update
    check_map_update_values(
        u.keyframe_id, [(kf.id, kf.T_world_cam, kf.map_point_ids) for kf in u.keyframes], u.point_ids, u.p_world,
        u.normals, u.min_distance_m, u.max_distance_m, u.removed_point_ids, u.removed_keyframe_ids,
    )
    return update


def _unpack_float(msg: pb.MapUpdate, name: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """Float64 values of map-update field ``name``: from its float32 field, or from the float64 one of
    recordings made before the float32 fields existed."""
    narrow = getattr(msg, f"{name}_f32")
    if narrow or not getattr(msg, name):
        return unpack(narrow, "<f4", shape, f"{where} {name}").astype(np.float64)
    return unpack(getattr(msg, name), "<f8", shape, f"{where} {name}")
