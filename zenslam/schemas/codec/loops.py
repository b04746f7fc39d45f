"""Loop reports (backend/loop): each loop candidate that reached verification, and what became of it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.codec.packing import parse, transform_from_pb, transform_to_pb


@dataclass(frozen=True)
class LoopMessage:
    """A loop candidate that reached verification (backend/loop): accepted, or rejected with a reason."""

    keyframe_id: int
    stamp_ns: int
    loop_keyframe_id: int
    loop_stamp_ns: int
    accepted: bool
    reason: str  # why it was rejected; "" when accepted
    T_world_cur_before: np.ndarray  # (4, 4) the current keyframe's pose before any correction
    T_world_loop: np.ndarray  # (4, 4) the loop keyframe's pose
    # The verified transform, for an accepted loop and for one refused after verification (drift
    # budget, pose graph); identity with 0 inliers for a candidate that failed verification.
    T_cur_loop: np.ndarray = field(default_factory=lambda: np.eye(4))  # (4, 4) rigid part: loop camera -> current camera
    scale: float = 1.0  # the transform's scale (1 for stereo/RGB-D)
    inliers: int = 0
    T_world_cur_after: np.ndarray = field(default_factory=lambda: np.eye(4))  # (4, 4) after the correction


def encode_loop(loop: LoopMessage) -> bytes:
    """Encode a backend/loop message."""
    msg = pb.Loop(
        keyframe_id=loop.keyframe_id, stamp_ns=loop.stamp_ns, loop_keyframe_id=loop.loop_keyframe_id,
        loop_stamp_ns=loop.loop_stamp_ns, accepted=loop.accepted, reason=loop.reason, scale=loop.scale, inliers=loop.inliers,
    )
    transform_to_pb(loop.T_world_cur_before, msg.T_world_cur_before)
    transform_to_pb(loop.T_world_loop, msg.T_world_loop)
    if loop.accepted or loop.inliers > 0:
        transform_to_pb(loop.T_cur_loop, msg.T_cur_loop)
    if loop.accepted:
        transform_to_pb(loop.T_world_cur_after, msg.T_world_cur_after)
    return msg.SerializeToString()


def decode_loop(data: bytes) -> LoopMessage:
    """Decode a backend/loop message (an unaccepted loop's pose after the correction is the identity,
    and so is the transform of one that failed verification)."""
    msg = parse(pb.Loop, data)
    accepted = bool(msg.accepted)
    verified = accepted or msg.inliers > 0
    return LoopMessage(
        keyframe_id=msg.keyframe_id, stamp_ns=msg.stamp_ns, loop_keyframe_id=msg.loop_keyframe_id,
        loop_stamp_ns=msg.loop_stamp_ns, accepted=accepted, reason=msg.reason,
        T_world_cur_before=transform_from_pb(msg.T_world_cur_before), T_world_loop=transform_from_pb(msg.T_world_loop),
        T_cur_loop=transform_from_pb(msg.T_cur_loop) if verified else np.eye(4),
        scale=msg.scale if verified else 1.0, inliers=msg.inliers,
        T_world_cur_after=transform_from_pb(msg.T_world_cur_after) if accepted else np.eye(4),
    )
