"""Camera poses as foxglove.PoseInFrame (frontend/pose): what Foxglove and rerun's MCAP reader draw."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from zenslam.errors import MessageError
from zenslam.geometry import R_to_quat_wxyz, quat_wxyz_to_R
from zenslam.schemas.codec.packing import parse

_NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class StampedPose:
    """A camera pose at a time: T_world_cam maps camera to ``frame_id`` coordinates."""

    stamp_ns: int
    T_world_cam: np.ndarray  # (4, 4)
    frame_id: str = "world"


def encode_pose_in_frame(pose: StampedPose) -> bytes:
    """Encode a pose as foxglove.PoseInFrame (what Foxglove and rerun's MCAP reader draw)."""
    msg = PoseInFrame(frame_id=pose.frame_id)
    seconds, nanos = divmod(int(pose.stamp_ns), _NS_PER_S)
    msg.timestamp.seconds, msg.timestamp.nanos = seconds, nanos
    T = np.asarray(pose.T_world_cam, dtype=float)
    if T.shape != (4, 4):
        raise MessageError(f"a pose must be a 4x4 transform, got shape {T.shape}")
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in T[:3, 3])
    w, x, y, z = R_to_quat_wxyz(T[:3, :3])
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = float(x), float(y), float(z), float(w)  # foxglove orders quaternions x, y, z, w
    return msg.SerializeToString()


def decode_pose_in_frame(data: bytes) -> StampedPose:
    """Decode a foxglove.PoseInFrame message."""
    msg = parse(PoseInFrame, data)
    o, p = msg.pose.orientation, msg.pose.position
    T = np.eye(4)
    T[:3, :3] = quat_wxyz_to_R(np.array([o.w, o.x, o.y, o.z]))
    T[:3, 3] = (p.x, p.y, p.z)
    stamp_ns = msg.timestamp.seconds * _NS_PER_S + msg.timestamp.nanos
    return StampedPose(stamp_ns, T, msg.frame_id)
