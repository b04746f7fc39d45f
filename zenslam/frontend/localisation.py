"""Localisation mode (ORB-SLAM2's mbOnlyTracking): frames placed in the backend's map without
making keyframes or points; with few map matches they go on by visual odometry and try to
relocalise at every frame, a relocalisation taken only near the odometry's pose
(``relocalisation.vo_agreement_*``). With a stereo camera the map's points are weighed by their
covariance (``point_uncertainty``) and the poses may be filtered with the odometry's
(``visual_odometry.fusion``, ``pose_filter``)."""

from __future__ import annotations

import logging
import time
import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.frontend.frame import Frame, frame_pose_information, optimize_frame_pose
from zenslam.frontend.frame_outcome import FrameOutcomes
from zenslam.frontend.local_map_tracking import LocalMapPose, LocalMapTracking
from zenslam.frontend.map_pose import MapPoseSolver
from zenslam.frontend.motion_model_tracking import MotionModelTracking
from zenslam.frontend.point_uncertainty import view_information
from zenslam.frontend.pose_filter import PoseEstimate, fuse, predict
from zenslam.frontend.reference_keyframe_tracking import ReferenceKeyframeTracking
from zenslam.frontend.relocalisation import PosePrior, pose_offset
from zenslam.frontend.relocalisation_tracking import CandidateSource, RelocalisationTracking
from zenslam.frontend.tracking_config import TrackingConfig
from zenslam.frontend.tracking_state import LastFrame, TrackerState, TrackingOutput, tracking_output
from zenslam.frontend.visual_odometry import OdometryPose, optimise_with_odometry
from zenslam.geometry import invert_T
from zenslam.pose_optimizer import PoseOptimizerConfig

logger = logging.getLogger(__name__)

class Localisation:
    """Tracks frames in localisation mode; its visual odometry's state is ``state.odometry``."""

    def __init__(
        self, state: TrackerState, config: TrackingConfig, calibration: PinholeCalibration, pose_config: PoseOptimizerConfig,
        solver: MapPoseSolver, motion_tracking: MotionModelTracking, reference_tracking: ReferenceKeyframeTracking,
        local_map_tracking: LocalMapTracking, relocalisation: RelocalisationTracking, outcomes: FrameOutcomes,
    ) -> None:
        self.state = state
        self.config = config
        self.calibration = calibration
        self.pose_config = pose_config
        self.solver = solver
        self.motion_tracking = motion_tracking
        self.reference_tracking = reference_tracking
        self.local_map_tracking = local_map_tracking
        self.relocalisation = relocalisation
        self._tracked = outcomes.tracked
        self._lost = outcomes.lost
        self.filters_poses = outcomes.filters_poses  # poses filtered with the odometry's (``pose_filter``)
        self.vo = state.odometry

    def track(self, frame: Frame, candidates: CandidateSource | None) -> TrackingOutput:
        """ORB-SLAM2's Track with mbOnlyTracking: the motion model with the last frame's map and VO
        points; a frame with enough map matches then tracks the local map (no keyframe). A frame on
        visual odometry, or whose local-map tracking fails while its odometry holds, keeps the
        odometry pose; the next frames also try to relocalise, and the first that does leaves VO."""
        timers = self.state.timers
        start, pose_ms = time.perf_counter(), timers.pose_ms
        odometry = self._track_odometry(frame)
        timers.add_less_pose("motion_model_tracking", start, pose_ms)
        if self.vo.on_vo and self.relocalisation.enabled(candidates):
            found, _ = self.relocalisation.relocalise(frame, candidates, self._odometry_prior(odometry))
            if found is not None:
                T_cam_world, rows, n_inliers, covariance = self._relocalised_with_odometry(frame, found, odometry)
                return self._tracked(frame, T_cam_world, rows, n_inliers, 0, relocalised=True, covariance=covariance)
        if odometry is None and not self.vo.on_vo:
            start, pose_ms = time.perf_counter(), timers.pose_ms
            odometry = self.reference_tracking.track(frame, self.state.reference_slot, self.state.last.T_cam_world)
            timers.add_less_pose("motion_model_tracking", start, pose_ms)
        if odometry is None:
            return self._lost(frame, "too_few_matches_visual_odometry" if self.vo.on_vo else "too_few_matches_motion_model_and_reference", 0)
        min_inliers = self.relocalisation.min_local_map_inliers
        if not self.vo.on_vo and not odometry.is_vo(self.config.visual_odometry):
            start, pose_ms = time.perf_counter(), timers.pose_ms
            local = self.local_map_tracking.track(frame, odometry.T_cam_world, odometry.rows)
            T_cam_world, rows, n_inliers = local.T_cam_world, local.rows, local.n_inliers
            joint_below = self.config.visual_odometry.joint_below_map_inliers
            covariance = None
            if (joint_below is None or n_inliers < joint_below) and len(odometry.vo_keypoints):
                T_cam_world, rows, n_inliers, covariance = self._with_odometry(frame, T_cam_world, rows, odometry)
            timers.add_less_pose("local_map_tracking", start, pose_ms)
            if n_inliers >= min_inliers(frame):
                return self._tracked(frame, T_cam_world, rows, n_inliers, 0, covariance=covariance)
        if odometry.n_total < self.config.visual_odometry.min_matches:
            return self._lost(frame, f"local_map_inliers_below_{min_inliers(frame)}", odometry.n_total)
        return self._tracked_by_odometry(frame, odometry)

    def _track_odometry(self, frame: Frame) -> OdometryPose | None:
        """The motion model (the last pose when it has no velocity) against the last frame's map and
        VO points, or on visual odometry against the anchor's (the last frame's when the anchor
        gives no pose); None with fewer than ``visual_odometry.min_matches`` inliers."""
        last, min_matches = self.state.last, self.config.visual_odometry.min_matches
        predicted = self.state.motion.predict(last.T_cam_world, self.state.frame_gap(frame))
        T_predicted = last.T_cam_world if predicted is None else predicted
        odometry = None
        anchored = self.config.visual_odometry.anchor_keep_ratio < 1.0
        self.vo.from_anchor = anchored and self.vo.on_vo and self.vo.anchor is not None
        if self.vo.from_anchor:
            odometry = self.motion_tracking.match(frame, self.vo.anchor, T_predicted, True)
            self.vo.from_anchor = odometry is not None and odometry.n_total >= min_matches
        if not self.vo.from_anchor:
            odometry = self.motion_tracking.match(frame, last, T_predicted, True)
        if odometry is None or odometry.n_total < min_matches:
            return None
        return odometry

    def _with_odometry(self, frame: Frame, T_cam_world: np.ndarray, rows: np.ndarray, odometry: OdometryPose):
        """The local-map pose steadied by the odometry's VO matches: (T, rows, map inliers, covariance).
        ``visual_odometry.fusion`` "filter": fused with the odometry's prediction (``pose_filter``);
        "exact_points": optimised again with the VO matches added as exact points (covariance None)."""
        if self.filters_poses:
            fused = self._fused_with_odometry(frame, T_cam_world, rows, odometry)
            return fused.T_cam_world, rows, int(np.count_nonzero(rows >= 0)), fused.covariance
        start = time.perf_counter()
        kps = np.flatnonzero(rows >= 0)
        T_cam_world, inliers = optimise_with_odometry(
            frame, T_cam_world, kps, self.solver.map.p_world[rows[kps]], odometry, self.pose_config,
            map_covariance=self.solver.covariance(rows[kps]),
        )  # fmt: skip
        self.state.timers.add("pose_optimization", start)
        rows = rows.copy()
        rows[kps[~inliers]] = -1
        return T_cam_world, rows, int(np.count_nonzero(inliers)), None

    def _relocalised_with_odometry(self, frame: Frame, found: LocalMapPose, odometry: OdometryPose | None):
        """A relocalisation ``found`` that ends visual odometry, fused with the odometry's prediction
        where localisation filters the poses: (T, rows, map inliers, covariance)."""
        T_cam_world, rows, n_inliers = found.T_cam_world, found.rows, found.n_inliers
        if not self.filters_poses or odometry is None or not len(odometry.vo_keypoints):
            return T_cam_world, rows, n_inliers, None
        fused = self._fused_with_odometry(frame, T_cam_world, rows, odometry)
        return fused.T_cam_world, rows, n_inliers, fused.covariance

    def _fused_with_odometry(self, frame: Frame, T_cam_world: np.ndarray, rows: np.ndarray, odometry: OdometryPose) -> PoseEstimate:
        """The pose ``T_cam_world`` from the map inliers ``rows`` fused with the odometry's prediction."""
        odometry_config = self.config.visual_odometry
        information = self.solver.information(frame, T_cam_world, rows) * odometry_config.filter_map_information_scale
        return fuse(T_cam_world, information, self.odometry_estimate(frame, odometry), odometry_config.filter_max_chi2)

    def odometry_estimate(self, frame: Frame, odometry: OdometryPose) -> PoseEstimate:
        """The frame as its odometry places it relative to the frame whose VO points it matched (the
        anchor or the last frame): the pose from those VO points alone, and the covariance carried
        from that frame plus the odometry's own (``pose_filter.predict``), each VO point weighed by
        the covariance of its one stereo view from that frame (this frame's keypoint's level standing
        for that frame's), bounded as the map's points are."""
        start = time.perf_counter()
        source = self.vo.anchor if self.vo.from_anchor else self.state.last
        kps, p_world = odometry.vo_keypoints, odometry.vo_p_world
        levels = frame.features.inv_level_sigma2[frame.features.level[kps]]
        view = view_information(source.T_cam_world, p_world, levels, np.ones(len(kps), dtype=bool), self.calibration)
        covariance = np.linalg.inv(view + np.eye(3) / self.config.localization_point_max_sigma_m**2)
        found = optimize_frame_pose(frame, odometry.T_cam_world, kps, p_world, self.pose_config, point_covariance=covariance)
        T_cam_world, information = odometry.T_cam_world, np.zeros((6, 6))  # no pose: the prediction says nothing
        if found.n_inliers:
            T_cam_world, inliers = found.T_cam_world, found.inliers
            information = frame_pose_information(frame, T_cam_world, kps[inliers], p_world[inliers], covariance[inliers])
        self.state.timers.add("pose_optimization", start)
        return predict(source.estimate(), T_cam_world, information)

    def _tracked_by_odometry(self, frame: Frame, odometry: OdometryPose) -> TrackingOutput:
        """A frame placed by visual odometry: the motion model goes on, the map is not touched."""
        state = self.state
        self.vo.on_vo = True
        self.vo.n_frames += 1
        self.vo.path_m += pose_offset(state.last.T_cam_world, odometry.T_cam_world)[0]
        covariance = None
        if self.filters_poses:
            covariance = self.odometry_estimate(frame, odometry).covariance
        self._keep_or_move_anchor(frame, odometry, covariance)
        state.motion.update(state.last.T_cam_world, odometry.T_cam_world, state.frame_gap(frame), state.elapsed_ns(frame))
        state.last = LastFrame(frame, odometry.rows, odometry.T_cam_world, covariance)
        state.lost_streak = 0
        logger.debug("frame %d on visual odometry: %d map, %d total matches", frame.index, odometry.n_map, odometry.n_total)
        T_world_cam = invert_T(odometry.T_cam_world)
        return tracking_output(frame, "ok", None, T_world_cam, odometry.n_map, None, state.timers.snapshot())

    def _odometry_prior(self, odometry: OdometryPose | None) -> PosePrior | None:
        """Where this frame's odometry puts it, and how far a relocalisation may lie from that: the
        configured allowance grown with the path on odometry up to this frame (None: no odometry
        pose, or no check configured)."""
        cfg = self.config.relocalisation
        if odometry is None or cfg.vo_agreement_m is None:
            return None
        path = self.vo.path_m + pose_offset(self.state.last.T_cam_world, odometry.T_cam_world)[0]
        return PosePrior(
            odometry.T_cam_world, cfg.vo_agreement_m + cfg.vo_agreement_per_m * path, cfg.vo_agreement_deg + cfg.vo_agreement_deg_per_m * path
        )

    def _keep_or_move_anchor(self, frame: Frame, odometry: OdometryPose, covariance: np.ndarray | None) -> None:
        """The frame (its pose's ``covariance``) becomes the VO anchor unless it was matched to the
        anchor and kept enough of it."""
        matches = len(odometry.vo_keypoints)
        if self.vo.from_anchor and self.vo.anchor_matches == 0:
            self.vo.anchor_matches = matches
        elif not self.vo.from_anchor or matches < self.config.visual_odometry.anchor_keep_ratio * self.vo.anchor_matches:
            self.vo.anchor = LastFrame(frame, odometry.rows, odometry.T_cam_world, covariance)
            self.vo.anchor_matches = 0
