"""Local-map tracking (ORB-SLAM2's TrackLocalMap): the points of the keyframes around the frame
matched by projection into its free keypoints, then the pose optimised on every match."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.frontend.feature_matcher import search_by_projection
from zenslam.frontend.frame import Frame
from zenslam.frontend.frustum import project_in_frustum
from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.local_window import local_point_rows, local_window
from zenslam.frontend.map_pose import MapPoseSolver
from zenslam.frontend.tracking_config import TrackingConfig
from zenslam.frontend.tracking_state import TrackerState
from zenslam.map_point_rules import radius_by_viewing_cos


@dataclass(frozen=True)
class LocalMapPose:
    """A frame's pose after local-map tracking and its map inliers."""

    T_cam_world: np.ndarray  # (4, 4) world -> camera
    rows: np.ndarray  # (N,) map row per keypoint, -1 none or outlier
    n_inliers: int


class LocalMapTracking:
    """Tracks frames in the local map; the local window's reference keyframe becomes ``state``'s."""

    def __init__(
        self, local_map: LocalMap, state: TrackerState, config: TrackingConfig, calibration: PinholeCalibration, sensor: SensorKind,
        solver: MapPoseSolver,
    ) -> None:
        self.map = local_map
        self.state = state
        self.config = config
        self.calibration = calibration
        self.sensor = sensor
        self.solver = solver

    def track(self, frame: Frame, T_cam_world: np.ndarray, rows: np.ndarray) -> LocalMapPose:
        """Match local points by projection from the pose ``T_cam_world`` and the matches ``rows``, optimise."""
        window = local_window(self.map, rows)
        if window.reference_slot >= 0:
            self.state.reference_slot = window.reference_slot
        local_rows = local_point_rows(self.map, window.keyframe_slots)
        matched = rows >= 0
        self.map.increase_visible(rows[matched])
        candidates = local_rows[~np.isin(local_rows, rows[matched])]
        self._search_local_points(frame, T_cam_world, rows, candidates)
        T_cam_world, inliers = self.solver.optimize(T_cam_world, frame, rows)
        self.map.increase_found(rows[inliers])
        rows = np.where(inliers, rows, -1)
        return LocalMapPose(T_cam_world, rows, int(np.count_nonzero(inliers)))

    def _search_local_points(self, frame: Frame, T_cam_world, rows: np.ndarray, candidates: np.ndarray) -> None:
        """Match the visible candidate points into the frame's free keypoints; fills ``rows`` in place."""
        if len(candidates) == 0:
            return
        feats = frame.features
        lm = self.map
        scales = feats.scale_factors
        proj = project_in_frustum(
            T_cam_world,
            lm.p_world[candidates],
            lm.normals[candidates],
            lm.min_distance_m[candidates],
            lm.max_distance_m[candidates],
            self.calibration,
            float(scales[1]) if len(scales) > 1 else 1.0,
            len(scales),
            self.config.min_view_cos,
        )
        visible = np.flatnonzero(proj.visible)
        lm.increase_visible(candidates[visible])
        if len(visible) == 0:
            return
        th = self.config.local_radius_rgbd if self.sensor == "rgbd" else self.config.local_radius_stereo
        level = proj.level[visible]
        radius = th * radius_by_viewing_cos(proj.view_cos[visible]) * feats.scale_factors[level]
        match = search_by_projection(
            proj.px[visible],
            level,
            lm.descriptors[candidates[visible]],
            feats.px,
            feats.level,
            feats.descriptors,
            radius,
            max_distance=self.config.max_descriptor_distance,
            ratio=self.config.local_ratio,
            already_matched=rows >= 0,
            min_level_offset=-1,
            max_level_offset=0,
            kp_right_u=frame.right_u,
            proj_right_u=proj.right_u[visible] if self.calibration.baseline_m is not None else None,
        )
        hit = match >= 0
        rows[match[hit].astype(np.int64)] = candidates[visible[hit]]
