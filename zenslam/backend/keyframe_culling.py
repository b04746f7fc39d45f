"""Redundant keyframe culling (ORB-SLAM's ``LocalMapping::KeyFrameCulling``).

A keyframe covisible with the new one is redundant when more than 90% of its map points (for
stereo/RGB-D only its close points, depth below ``close_depth_baselines`` baselines) are seen by
at least three other keyframes at the same or a finer scale (keypoint level at most one above its
own). The first keyframe (the gauge) and keyframes holding a loop edge are never culled. Culling
removes the keyframe's observations, re-attaches its spanning-tree children and updates the
covisibility graph (``BackendMap.remove_keyframe``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from zenslam.backend.map import BackendMap

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class KeyframeCullingConfig:
    """ORB-SLAM's redundancy test."""

    enabled: bool = True  # cull redundant keyframes at all
    redundant_fraction: float = 0.9  # culled when more than this fraction of its points is redundant
    min_other_observers: int = 3  # other keyframes that must see a point for it to be redundant
    level_margin: int = 1  # those keyframes' keypoint level may exceed this keyframe's by this much
    close_depth_baselines: float = 40.0  # stereo/RGB-D: only points closer than this x baseline count (ThDepth)


def is_redundant(bmap: BackendMap, kf_id: int, config: KeyframeCullingConfig) -> bool:
    """Whether keyframe ``kf_id`` is redundant under ORB-SLAM's rule."""
    kf = bmap.keyframe(kf_id)
    keypoints = np.flatnonzero(kf.map_point_ids >= 0)
    if kf.sensor != "mono":
        th_depth = config.close_depth_baselines * (kf.calibration.baseline_m or 0.0)
        depth = kf.depth_m[keypoints]
        keypoints = keypoints[(depth >= 0) & (depth <= th_depth)]
    n_redundant = 0
    for keypoint in keypoints.tolist():
        pt = bmap.points[int(kf.map_point_ids[keypoint])]
        if len(pt.observations) - 1 < config.min_other_observers:
            continue
        max_level = kf.levels[keypoint] + config.level_margin
        seen = 0
        for other, other_keypoint in pt.observations.items():
            if other != kf_id and bmap.keyframes[other].levels[other_keypoint] <= max_level:
                seen += 1
                if seen >= config.min_other_observers:
                    n_redundant += 1
                    break
    return n_redundant > config.redundant_fraction * len(keypoints)


def cull_redundant_keyframes(bmap: BackendMap, current_id: int, config: KeyframeCullingConfig) -> tuple[list[int], list[int]]:
    """Remove the redundant keyframes among those connected to ``current_id`` (checked in connection
    order, each against the map left by the previous removals).

    Returns (culled keyframe ids, ids of points that lost an observation)."""
    if not config.enabled:
        return [], []
    culled: list[int] = []
    touched: list[int] = []
    for kf_id in bmap.covisibility.connected(current_id):
        if kf_id == bmap.first_keyframe_id or bmap.essential_graph.has_loop_edge(kf_id):
            continue
        if is_redundant(bmap, kf_id, config):
            touched.extend(bmap.remove_keyframe(kf_id))
            culled.append(kf_id)
    if culled:
        logger.debug("keyframe %d: culled redundant keyframes %s", current_id, culled)
    return culled, touched
