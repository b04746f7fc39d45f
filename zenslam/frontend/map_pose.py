"""A frame's pose from its matches to the map cache's points: optimisation and information, each
point exact or weighed by its position covariance (localisation mode with a stereo camera)."""

from __future__ import annotations

import time

import numpy as np

from zenslam.frontend.frame import Frame, frame_pose_information, optimize_frame_pose
from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.tracking_state import StageTimers
from zenslam.pose_optimizer import PoseOptimizerConfig


class MapPoseSolver:
    """Pose optimisation of frames matched to map rows, timed under "pose_optimization".

    ``weighs_points``: each map point is weighed by its covariance (``LocalMap.covariance``) instead
    of being taken as exact.
    """

    def __init__(self, local_map: LocalMap, pose_config: PoseOptimizerConfig, timers: StageTimers, weighs_points: bool) -> None:
        self.map = local_map
        self.pose_config = pose_config
        self.timers = timers
        self.weighs_points = weighs_points

    def covariance(self, rows: np.ndarray) -> np.ndarray | None:
        """The position covariances (K, 3, 3) of map ``rows`` (K,) to weigh them by in pose
        optimisation; None (points exact) where the points are not weighed."""
        return self.map.covariance[rows] if self.weighs_points else None

    def optimize(self, T_cam_world: np.ndarray, frame: Frame, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose optimisation of ``frame`` matched to map rows (N,) -1 none; returns (T, inlier mask (N,))."""
        start = time.perf_counter()
        kps = np.flatnonzero(rows >= 0)
        result = optimize_frame_pose(
            frame, T_cam_world, kps, self.map.p_world[rows[kps]], self.pose_config, point_covariance=self.covariance(rows[kps])
        )
        inliers = np.zeros(len(rows), dtype=bool)
        inliers[kps] = result.inliers
        self.timers.add("pose_optimization", start)
        return result.T_cam_world, inliers

    def information(self, frame: Frame, T_cam_world: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(6, 6) information of the pose from the frame's map inliers ``rows``, weighed as tracking
        weighs them."""
        start = time.perf_counter()
        kps = np.flatnonzero(rows >= 0)
        information = frame_pose_information(frame, T_cam_world, kps, self.map.p_world[rows[kps]], self.covariance(rows[kps]))
        self.timers.add("pose_optimization", start)
        return information
