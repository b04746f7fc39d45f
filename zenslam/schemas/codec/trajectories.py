"""The backend's trajectory and map replies (backend/trajectory, backend/map): keyframe poses, and map points."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from zenslam.errors import MessageError
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.codec.packing import pack, parse, unpack


@dataclass(frozen=True)
class KeyframeTrajectoryMessage:
    """Keyframe poses oldest first (the backend/trajectory reply); K keyframes."""

    keyframe_ids: np.ndarray  # (K,) int64
    stamps_ns: np.ndarray  # (K,) int64
    T_world_cam: np.ndarray  # (K, 4, 4) camera -> world
    keyframes_processed: int = 0  # keyframes the backend had processed when it answered
    finished: bool = False  # the backend had processed its input's end of stream
    # Keyframes culled from the map (C), each where its spanning-tree parent's correction put it.
    culled_keyframe_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (C,) int64
    culled_stamps_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (C,) int64
    culled_T_world_cam: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))  # (C, 4, 4)
    # The first ids a frontend continuing this map may use (a restarted frontend): past every keyframe
    # and frontend point id the backend knows, mapped, culled, fused away or waiting in its inbox.
    next_keyframe_id: int = 0
    next_frontend_point_id: int = 0


@dataclass(frozen=True)
class MapSnapshotMessage:
    """The backend's map (the backend/map reply): keyframe poses and P point positions."""

    keyframes: KeyframeTrajectoryMessage
    point_ids: np.ndarray  # (P,) int64
    p_world: np.ndarray  # (P, 3) metres, world frame


def _trajectory_to_pb(trajectory: KeyframeTrajectoryMessage, out: pb.KeyframeTrajectory) -> None:
    k = len(trajectory.keyframe_ids)
    if len(trajectory.stamps_ns) != k or np.shape(trajectory.T_world_cam) != (k, 4, 4):
        raise MessageError(
            f"keyframe trajectory: {k} ids, {len(trajectory.stamps_ns)} stamps and poses of shape "
            f"{np.shape(trajectory.T_world_cam)} do not agree (expected ({k}, 4, 4))"
        )
    out.keyframes_processed, out.finished, out.num_keyframes = trajectory.keyframes_processed, trajectory.finished, k
    out.next_keyframe_id, out.next_frontend_point_id = trajectory.next_keyframe_id, trajectory.next_frontend_point_id
    out.keyframe_ids = pack(trajectory.keyframe_ids, "<i8", (), "keyframe trajectory keyframe_ids")
    out.stamps_ns = pack(trajectory.stamps_ns, "<i8", (), "keyframe trajectory stamps_ns")
    out.T_world_cam = pack(trajectory.T_world_cam, "<f8", (4, 4), "keyframe trajectory T_world_cam")
    c = len(trajectory.culled_keyframe_ids)
    if len(trajectory.culled_stamps_ns) != c or np.shape(trajectory.culled_T_world_cam) != (c, 4, 4):
        raise MessageError(
            f"keyframe trajectory: {c} culled ids, {len(trajectory.culled_stamps_ns)} stamps and poses of shape "
            f"{np.shape(trajectory.culled_T_world_cam)} do not agree (expected ({c}, 4, 4))"
        )
    if c:
        out.num_culled = c
        out.culled_keyframe_ids = pack(trajectory.culled_keyframe_ids, "<i8", (), "keyframe trajectory culled_keyframe_ids")
        out.culled_stamps_ns = pack(trajectory.culled_stamps_ns, "<i8", (), "keyframe trajectory culled_stamps_ns")
        out.culled_T_world_cam = pack(trajectory.culled_T_world_cam, "<f8", (4, 4), "keyframe trajectory culled_T_world_cam")


def _trajectory_from_pb(msg: pb.KeyframeTrajectory) -> KeyframeTrajectoryMessage:
    k, c = msg.num_keyframes, msg.num_culled
    return KeyframeTrajectoryMessage(
        keyframe_ids=unpack(msg.keyframe_ids, "<i8", (k,), "keyframe trajectory keyframe_ids"),
        stamps_ns=unpack(msg.stamps_ns, "<i8", (k,), "keyframe trajectory stamps_ns"),
        T_world_cam=unpack(msg.T_world_cam, "<f8", (k, 4, 4), "keyframe trajectory T_world_cam"),
        keyframes_processed=msg.keyframes_processed,
        finished=msg.finished,
        culled_keyframe_ids=unpack(msg.culled_keyframe_ids, "<i8", (c,), "keyframe trajectory culled_keyframe_ids"),
        culled_stamps_ns=unpack(msg.culled_stamps_ns, "<i8", (c,), "keyframe trajectory culled_stamps_ns"),
        culled_T_world_cam=unpack(msg.culled_T_world_cam, "<f8", (c, 4, 4), "keyframe trajectory culled_T_world_cam"),
        next_keyframe_id=msg.next_keyframe_id,
        next_frontend_point_id=msg.next_frontend_point_id,
    )


def encode_keyframe_trajectory(trajectory: KeyframeTrajectoryMessage) -> bytes:
    """Encode a backend/trajectory reply."""
    msg = pb.KeyframeTrajectory()
    _trajectory_to_pb(trajectory, msg)
    return msg.SerializeToString()


def decode_keyframe_trajectory(data: bytes) -> KeyframeTrajectoryMessage:
    """Decode a backend/trajectory reply."""
    return _trajectory_from_pb(parse(pb.KeyframeTrajectory, data))


def encode_map_snapshot(snapshot: MapSnapshotMessage) -> bytes:
    """Encode a backend/map reply; point ids and positions must agree in length."""
    p = len(snapshot.point_ids)
    if len(snapshot.p_world) != p:
        raise MessageError(f"map snapshot: {len(snapshot.p_world)} point positions for {p} point ids")
    msg = pb.MapSnapshot(num_points=p)
    _trajectory_to_pb(snapshot.keyframes, msg.keyframes)
    msg.point_ids = pack(snapshot.point_ids, "<i8", (), "map snapshot point_ids")
    msg.p_world = pack(snapshot.p_world, "<f8", (3,), "map snapshot p_world")
    return msg.SerializeToString()


def decode_map_snapshot(data: bytes) -> MapSnapshotMessage:
    """Decode a backend/map reply."""
    msg = parse(pb.MapSnapshot, data)
    p = msg.num_points
    return MapSnapshotMessage(
        keyframes=_trajectory_from_pb(msg.keyframes),
        point_ids=unpack(msg.point_ids, "<i8", (p,), "map snapshot point_ids"),
        p_world=unpack(msg.p_world, "<f8", (p, 3), "map snapshot p_world"),
    )
