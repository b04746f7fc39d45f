"""A monocular map's first two keyframes: bundle adjustment of both, at the scale the frontend chose.

The frontend starts a monocular map from a two-view reconstruction (``frontend.monocular_initialisation``):
a linear triangulation whose motion direction is only as good as its small parallax allows, scaled so
that the first keyframe's points have median depth 1. ORB-SLAM then runs a full BA of the two
keyframes and sets the median depth to 1 again (CreateInitialMapMonocular); local BA would wait for a
third keyframe. Here that BA runs when the map's second monocular keyframe arrives, so the answer to
it carries the refined map. The frontend has already published the second frame's pose by then, so
the map is scaled back to the distance between the two keyframes it had before the BA, not to a new
median depth: the poses that follow continue at the published scale.
"""

from __future__ import annotations

import logging

import numpy as np

from zenslam.backend.map import BackendMap

logger = logging.getLogger(__name__)


def is_monocular_map_start(bmap: BackendMap, kf_id: int) -> bool:
    """``kf_id`` is the second keyframe of a monocular map."""
    return len(bmap.keyframes) == 2 and bmap.keyframes[kf_id].sensor == "mono"


def baseline(bmap: BackendMap) -> float:
    """Distance between the first two keyframes' camera centres (map units)."""
    first, second = sorted(bmap.keyframes)[:2]
    return float(np.linalg.norm(bmap.keyframes[second].T_world_cam[:3, 3] - bmap.keyframes[first].T_world_cam[:3, 3]))


def rescale_about_first_keyframe(bmap: BackendMap, scale: float) -> None:
    """Scale every keyframe position and point by ``scale`` about the first keyframe's camera centre."""
    centre = bmap.keyframes[bmap.first_keyframe_id].T_world_cam[:3, 3].copy()
    for kf_id in sorted(bmap.keyframes):
        T = bmap.keyframes[kf_id].T_world_cam.copy()
        T[:3, 3] = centre + scale * (T[:3, 3] - centre)
        bmap.set_keyframe_pose(kf_id, T)
    point_ids = sorted(bmap.points)
    if point_ids:
        p_world = np.stack([bmap.points[p].p_world for p in point_ids])
        bmap.set_point_positions(point_ids, centre + scale * (p_world - centre))
    bmap.refresh_points()
