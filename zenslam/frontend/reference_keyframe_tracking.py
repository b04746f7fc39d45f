"""Tracking by the reference keyframe: its points matched to the frame by descriptor (ORB-SLAM2's
TrackReferenceKeyFrame), the pose optimised from the last frame's."""

from __future__ import annotations

import numpy as np

from zenslam.frontend.feature_matcher import match_by_descriptor, rotation_consistent
from zenslam.frontend.frame import Frame
from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.map_pose import MapPoseSolver
from zenslam.frontend.tracking_config import TrackingConfig
from zenslam.frontend.visual_odometry import OdometryPose


class ReferenceKeyframeTracking:
    """Matches frames to a keyframe's points by descriptor."""

    def __init__(self, local_map: LocalMap, config: TrackingConfig, solver: MapPoseSolver) -> None:
        self.map = local_map
        self.config = config
        self.solver = solver

    def track(self, frame: Frame, reference_slot: int, T_cam_world_last: np.ndarray) -> OdometryPose | None:
        """Match the frame to the points of the keyframe in ``reference_slot`` by descriptor; pose
        optimised from ``T_cam_world_last``; None with fewer than ``min_pose_inliers`` inliers.

        ORB-SLAM2 matches by bag of words against the keyframe's keypoint descriptors; here a
        brute-force ratio test against the points' representative descriptors, keeping ORB-SLAM's
        thresholds and rotation check (angles of the keyframe's keypoints).
        """
        if reference_slot < 0:
            return None
        keyframe = self.map.keyframe(reference_slot)
        if keyframe is None:
            return None
        kf_rows = self.map.rows_of_ids(keyframe.map_point_ids)
        kf_kps = np.flatnonzero(kf_rows >= 0)
        kf_kps = kf_kps[self.map.valid[kf_rows[kf_kps]]]
        feats = frame.features
        pairs = match_by_descriptor(
            self.map.descriptors[kf_rows[kf_kps]],  # the points' representative descriptors
            feats.descriptors,
            max_distance=self.config.reference_max_distance,
            ratio=self.config.reference_ratio,
        )
        if self.config.check_orientation and len(pairs):
            keep = rotation_consistent(keyframe.angle_deg[kf_kps[pairs[:, 0]]] - feats.angle_deg[pairs[:, 1]])
            pairs = pairs[keep]
        if len(pairs) < self.config.reference_min_matches:
            return None
        rows = np.full(len(feats), -1, dtype=np.int64)
        rows[pairs[:, 1]] = kf_rows[kf_kps[pairs[:, 0]]]
        T_cam_world, inliers = self.solver.optimize(T_cam_world_last, frame, rows)
        n_inliers = int(np.count_nonzero(inliers))
        if n_inliers < self.config.min_pose_inliers:
            return None
        return OdometryPose(T_cam_world, np.where(inliers, rows, -1), n_inliers, n_inliers)
