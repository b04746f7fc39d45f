"""A monocular map's first two keyframes: bundle adjustment of both, then the map's unit fixed again.

The frontend starts a monocular map from a two-view reconstruction (``frontend.monocular_initialisation``):
a linear triangulation whose motion direction is only as good as its small parallax allows. ORB-SLAM
then runs a full BA of the two keyframes and rescales the map so that the first keyframe's points have
median depth 1 (CreateInitialMapMonocular); local BA would wait for a third keyframe. Here that happens
when the map's second monocular keyframe arrives, so the answer to it carries the refined map.
"""

from __future__ import annotations

import logging

import numpy as np

from zenslam.backend.map import BackendMap
from zenslam.backend.triangulation import scene_median_depth

logger = logging.getLogger(__name__)


def is_monocular_map_start(bmap: BackendMap, kf_id: int) -> bool:
    """``kf_id`` is the second keyframe of a monocular map."""
    return len(bmap.keyframes) == 2 and bmap.keyframes[kf_id].sensor == "mono"


def rescale_to_median_depth(bmap: BackendMap, median_depth: float = 1.0) -> float | None:
    """Scale the map about its first keyframe's camera centre so that the first keyframe's points
    have ``median_depth``; returns the factor applied, None when it has no point in front of it."""
    first = bmap.keyframes[bmap.first_keyframe_id]
    depth = scene_median_depth(bmap, first)
    if depth is None or not depth > 0:
        logger.warning("monocular map start: the first keyframe's points have median depth %s; map left unscaled", depth)
        return None
    scale = median_depth / depth
    centre = first.T_world_cam[:3, 3].copy()
    for kf_id in sorted(bmap.keyframes):
        T = bmap.keyframes[kf_id].T_world_cam.copy()
        T[:3, 3] = centre + scale * (T[:3, 3] - centre)
        bmap.set_keyframe_pose(kf_id, T)
    point_ids = sorted(bmap.points)
    if point_ids:
        p_world = np.stack([bmap.points[p].p_world for p in point_ids])
        bmap.set_point_positions(point_ids, centre + scale * (p_world - centre))
    bmap.refresh_points()
    return scale

