"""A keyframe placed on the backend's map as it is inserted: a pose-only optimisation on its observations.

A keyframe is tracked on the frontend's copy of the map, which lags the backend's by the map
updates still on their way. The local BA of the keyframe moves it onto the backend's map; but while
keyframes wait behind it, local mapping defers that BA (ORB-SLAM's CheckNewKeyFrames), and the
keyframe stays where the older map put it. Its answer then sends that pose back to the frontend,
which had already moved the keyframe with its parent's correction: the frames tracked against it
jump back, and forward again once a BA reaches it. Placed by the pose-only optimisation of its
observations of the backend's points (not those it created), with the points it created moved
along, the keyframe starts where its BA would put its pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from zenslam.backend.keyframe import BackendKeyframe
from zenslam.backend.map import BackendMap
from zenslam.geometry import invert_T
from zenslam.pose_optimizer import PoseOptimizerConfig, optimize_pose


@dataclass(frozen=True)
class PlacementConfig:
    """When and how a keyframe inserted without its local BA is placed on the map."""

    enabled: bool = True  # place a keyframe whose fusion and local BA wait for queued keyframes
    # Inlier observations the pose-only optimisation must keep, else the keyframe stays as sent
    # (the frontend's threshold for a frame tracked in the local map).
    min_inliers: int = 30
    pose: PoseOptimizerConfig = field(default_factory=PoseOptimizerConfig)


def placement(bmap: BackendMap, keyframe: BackendKeyframe, config: PlacementConfig) -> np.ndarray | None:
    """The correction C (4x4, world frame) that places ``keyframe`` (not yet in ``bmap``) on the map:
    its pose becomes C @ T_world_cam, the pose-only optimisation of its associations with the map's
    points; None when fewer than ``config.min_inliers`` of them agree on one."""
    keypoints = np.flatnonzero(keyframe.map_point_ids >= 0)
    if len(keypoints) < config.min_inliers:
        return None
    right_u = keyframe.right_u[keypoints]
    result = optimize_pose(
        keyframe.T_cam_world,
        bmap.positions(keyframe.map_point_ids[keypoints]),
        keyframe.keypoints_px[keypoints],
        np.where(right_u >= 0, right_u, np.nan),
        1.0 / keyframe.level_sigma2[keyframe.levels[keypoints]],
        keyframe.calibration,
        config.pose,
    )
    if result.n_inliers < config.min_inliers:
        return None
    return invert_T(result.T_cam_world) @ keyframe.T_cam_world
