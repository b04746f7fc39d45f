"""The backend/loop messages of one keyframe's loop closing: each verified candidate, accepted or rejected."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from zenslam.backend.map import BackendMap
from zenslam.schemas import codec

if TYPE_CHECKING:
    from zenslam.backend.loop_closing import LoopOutcome
    from zenslam.backend.loop_verification import LoopMatch


def _stamp(bmap: BackendMap, kf_id: int) -> int:
    return bmap.keyframes[kf_id].stamp_ns if kf_id in bmap.keyframes else 0


def _pose(bmap: BackendMap, kf_id: int) -> np.ndarray:
    return bmap.keyframes[kf_id].T_world_cam.copy() if kf_id in bmap.keyframes else np.eye(4)


def _verified(match: LoopMatch | None) -> dict:
    """The LoopMessage fields of a verified match: its transform (rigid part and scale) and inliers."""
    if match is None:
        return {}
    return {"T_cur_loop": match.T_cur_loop.copy(), "scale": match.scale, "inliers": match.inliers}


def loop_messages(bmap: BackendMap, outcome: LoopOutcome, T_world_cur_before: np.ndarray) -> list[codec.LoopMessage]:
    """Rejected candidates in the order they were tried, then the accepted loop (poses as the map
    holds them now, after the correction). A candidate refused after verification (drift budget,
    pose graph) carries the transform it asked for."""
    kf_id = outcome.detection.keyframe_id
    stamp = _stamp(bmap, kf_id)
    messages = [
        codec.LoopMessage(
            keyframe_id=kf_id, stamp_ns=stamp, loop_keyframe_id=r.loop_keyframe_id, loop_stamp_ns=_stamp(bmap, r.loop_keyframe_id),
            accepted=False, reason=r.reason, T_world_cur_before=T_world_cur_before, T_world_loop=_pose(bmap, r.loop_keyframe_id),
            **_verified(r.match),
        )
        for r in outcome.rejections
    ]
    loop = outcome.loop
    if loop is not None:
        messages.append(
            codec.LoopMessage(
                keyframe_id=kf_id, stamp_ns=stamp, loop_keyframe_id=loop.loop_keyframe_id,
                loop_stamp_ns=_stamp(bmap, loop.loop_keyframe_id), accepted=True, reason="",
                T_world_cur_before=T_world_cur_before, T_world_loop=_pose(bmap, loop.loop_keyframe_id),
                T_world_cur_after=_pose(bmap, kf_id), **_verified(loop),
            )
        )
    return messages
