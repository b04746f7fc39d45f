"""Tracking by the last frame: its points matched by projection at a predicted pose (ORB-SLAM2's
TrackWithMotionModel), and the same matching with its visual-odometry points for localisation."""

from __future__ import annotations

import numpy as np

from zenslam.frontend.frame import Frame
from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.map_pose import MapPoseSolver
from zenslam.frontend.tracking_config import TrackingConfig
from zenslam.frontend.tracking_state import LastFrame
from zenslam.frontend.visual_odometry import LastFrameSearch, OdometryPose, last_frame_points, track_last_frame
from zenslam.pose_optimizer import PoseOptimizerConfig


class MotionModelTracking:
    """Matches frames to the last tracked frame's map points (and VO points) by projection;
    ``th_depth_m`` is the close-depth threshold below which a keypoint's depth makes a VO point."""

    def __init__(
        self, local_map: LocalMap, config: TrackingConfig, pose_config: PoseOptimizerConfig, solver: MapPoseSolver, th_depth_m: float
    ) -> None:
        self.map = local_map
        self.config = config
        self.pose_config = pose_config
        self.solver = solver
        self.th_depth_m = th_depth_m

    def track(self, frame: Frame, last: LastFrame, T_predicted: np.ndarray) -> OdometryPose | None:
        """ORB-SLAM2's TrackWithMotionModel: the last frame's points (with its VO points for a
        stereo/RGB-D camera) matched by projection with the predicted pose, the pose optimised; None
        with fewer than ``min_pose_inliers`` map inliers. The VO matches end here: local-map tracking
        starts from the map inliers and this pose."""
        odometry = self.match(frame, last, T_predicted, self.config.visual_odometry.in_slam_mode)
        if odometry is None or odometry.n_map < self.config.min_pose_inliers:
            return None
        return odometry

    def match(self, frame: Frame, source: LastFrame, T_predicted: np.ndarray, with_vo_points: bool) -> OdometryPose | None:
        """``track_last_frame`` on the valid map points and, ``with_vo_points``, the VO points of
        the frame ``source``."""
        lm, cfg = self.map, self.config
        close_depth_m, max_points = (self.th_depth_m, cfg.visual_odometry.max_points) if with_vo_points else (-1.0, 0)
        points = last_frame_points(
            source.frame, source.rows, source.T_cam_world, lm.p_world, lm.descriptors, lm.valid, close_depth_m, max_points
        )
        search = LastFrameSearch(
            cfg.motion_radius_px, cfg.motion_wide_factor, cfg.motion_min_matches, cfg.max_descriptor_distance, cfg.check_orientation
        )
        on_map = points.rows >= 0
        map_covariance, covariance = self.solver.covariance(points.rows[on_map]), None
        if map_covariance is not None:  # VO points, made from this camera's own depths, stay exact
            covariance = np.zeros((len(on_map), 3, 3))
            covariance[on_map] = map_covariance
        return track_last_frame(frame, source.frame, points, T_predicted, search, self.pose_config, covariance)
