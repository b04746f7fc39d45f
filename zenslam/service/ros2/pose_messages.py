"""zenslam's results as ROS 2 messages: geometry_msgs/PoseStamped, nav_msgs/Path and tf2_msgs/TFMessage (CDR).

Poses are T_parent_child (4x4, metres): the child frame's coordinates mapped into the parent's;
ROS quaternions are (x, y, z, w).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from zenslam.errors import MessageError
from zenslam.geometry import R_to_quat_wxyz
from zenslam.service.ros2 import cdr


def _check_T(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise MessageError(f"{what} must be a finite 4x4 transform, got shape {T.shape}")
    return T


def _pose(T_parent_child: np.ndarray) -> Any:
    """geometry_msgs/msg/Pose of a 4x4 transform."""
    T = _check_T(T_parent_child, "a pose")
    w, x, y, z = R_to_quat_wxyz(T[:3, :3])
    point = cdr.msg_class("geometry_msgs/msg/Point")(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3]))
    quaternion = cdr.msg_class("geometry_msgs/msg/Quaternion")(x=float(x), y=float(y), z=float(z), w=float(w))
    return cdr.msg_class("geometry_msgs/msg/Pose")(position=point, orientation=quaternion)


def _pose_stamped(stamp_ns: int, frame_id: str, T_frame_body: np.ndarray) -> Any:
    return cdr.msg_class(cdr.POSE_STAMPED)(header=cdr.header(stamp_ns, frame_id), pose=_pose(T_frame_body))


def encode_pose_stamped(stamp_ns: int, frame_id: str, T_frame_body: np.ndarray) -> bytes:
    """A geometry_msgs/msg/PoseStamped: the body (camera) pose T_frame_body in ``frame_id`` at ``stamp_ns``."""
    return cdr.serialize(_pose_stamped(stamp_ns, frame_id, T_frame_body), cdr.POSE_STAMPED)


def encode_path(stamp_ns: int, frame_id: str, stamps_ns: Sequence[int] | np.ndarray, T_frame_body: np.ndarray) -> bytes:
    """A nav_msgs/msg/Path stamped ``stamp_ns``: one PoseStamped per (stamp, T_frame_body (N, 4, 4)) in order."""
    poses = np.asarray(T_frame_body, dtype=float).reshape(-1, 4, 4) if len(stamps_ns) else np.zeros((0, 4, 4))
    if len(poses) != len(stamps_ns):
        raise MessageError(f"a Path needs one pose per stamp: {len(stamps_ns)} stamps, {len(poses)} poses")
    msg = cdr.msg_class(cdr.PATH)(
        header=cdr.header(stamp_ns, frame_id),
        poses=[_pose_stamped(int(stamp), frame_id, T) for stamp, T in zip(stamps_ns, poses, strict=True)],
    )
    return cdr.serialize(msg, cdr.PATH)


def encode_tf(stamp_ns: int, parent_frame_id: str, child_frame_id: str, T_parent_child: np.ndarray) -> bytes:
    """A tf2_msgs/msg/TFMessage of one transform: the child frame's pose in the parent frame."""
    T = _check_T(T_parent_child, "a transform")
    w, x, y, z = R_to_quat_wxyz(T[:3, :3])
    transform = cdr.msg_class("geometry_msgs/msg/Transform")(
        translation=cdr.msg_class("geometry_msgs/msg/Vector3")(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
        rotation=cdr.msg_class("geometry_msgs/msg/Quaternion")(x=float(x), y=float(y), z=float(z), w=float(w)),
    )
    stamped = cdr.msg_class("geometry_msgs/msg/TransformStamped")(
        header=cdr.header(stamp_ns, parent_frame_id), child_frame_id=child_frame_id, transform=transform
    )
    return cdr.serialize(cdr.msg_class(cdr.TF_MESSAGE)(transforms=[stamped]), cdr.TF_MESSAGE)
