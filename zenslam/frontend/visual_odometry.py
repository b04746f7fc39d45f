"""The motion-model match against the last frame: its map points and its temporary visual-odometry points (ORB-SLAM2).

ORB-SLAM2's ``UpdateLastFrame`` adds temporary points to a stereo or RGB-D last frame: its
keypoints with a depth but no map point (or one culled since), nearest first, all those closer than the close-depth
threshold and at least ``max_points``, back-projected from the last frame's pose. Its
``TrackWithMotionModel`` matches the map points and these visual-odometry (VO) points by projection
with the predicted pose (``track_last_frame``) and optimises the pose; the VO points are then
dropped: they never become map points, and no keyframe observes them.

They keep the motion-model match going where the map is thin or late. In SLAM mode
(``VisualOdometryConfig.in_slam_mode``) that is a last frame whose map points the backend has since
removed or fused into others, or a map that has had no new keyframe for a while because local
mapping is behind: the last frame's near depths still tie the frame to the one before, and the
pose they give starts local-map tracking, which places the frame on the map's points alone.
In localisation mode no keyframe, hence no point, is made: a frame with fewer than
``min_map_matches`` map inliers is *VO* and skips local-map tracking until a relocalisation finds
the map again. Unlike ORB-SLAM2, whose odometry chains frame to frame, a frame on VO is matched to
the VO points of an anchor frame, which it keeps while enough of them are matched
(``anchor_keep_ratio``). A localisation frame that does track the local map is steadied by its
VO matches: the map cannot be refined in this mode, and a frame that sees its points only from
afar, where stereo placed them to within centimetres, is held by the last frame's near depths
(``joint_below_map_inliers`` limits it to frames on few map points). By default (``fusion``
"filter") its pose from the map is fused with the odometry's prediction, each with its covariance
(``frontend/pose_filter.py``); "exact_points" optimises it once more with the VO matches added as
exact points (``optimise_with_odometry``), as ORB-SLAM2's ``TrackLocalMap`` keeps the frame's
matches to the temporary points of the motion-model step.

Plain numpy: the tracker owns the state (which frame is last, whether it was VO).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.errors import ConfigError
from zenslam.frontend.feature_matcher import rotation_consistent, search_by_projection
from zenslam.frontend.frame import Frame, optimize_frame_pose
from zenslam.frontend.keyframe import unproject_keypoints
from zenslam.pose_optimizer import PoseOptimizerConfig
from zenslam.geometry import invert_T


@dataclass(frozen=True)
class VisualOdometryConfig:
    """The last frame's VO points, and localisation mode's visual odometry (ORB-SLAM2's values)."""

    # Stereo/RGB-D SLAM mode matches the last frame's VO points in the motion-model step too
    # (ORB-SLAM2 makes them in localisation mode only). Unlike ORB-SLAM2's localisation mode, their
    # matches do not join the local-map pose optimisation: the last frame's raw depths would weigh
    # on every pose as much as the map's bundle-adjusted points, and bring their stereo bias with them.
    in_slam_mode: bool = True
    min_map_matches: int = 10  # fewer inlier matches to map points: the frame is on visual odometry
    min_matches: int = 20  # inlier matches (map and VO points) a pose needs, else the frame is lost
    max_points: int = 100  # VO points made beyond the close-depth threshold, nearest first
    # Localisation mode: a frame tracked in the map is optimised once more with its VO matches added
    # when it has fewer inlier map matches than this (None: always, as ORB-SLAM2; 0: never; the
    # measurements are in benchmarks/saved_maps.md).
    joint_below_map_inliers: int | None = None
    # Localisation mode: a frame on visual odometry is matched to the VO points of an anchor frame
    # (the first frame on VO, then each frame that re-anchors) rather than of the last frame, so the
    # pose drifts once per anchor rather than once per frame. A frame re-anchors when it keeps fewer
    # VO matches than this fraction of the first frame matched to the anchor, or when the anchor
    # gives no pose (it is then matched to the last frame, as ORB-SLAM2 does). 1.0: every frame is
    # an anchor (ORB-SLAM2's frame-to-frame odometry).
    anchor_keep_ratio: float = 0.5
    # Localisation mode: how the VO matches steady a frame tracked in the map. "filter": its pose
    # from the map alone is fused with the odometry's prediction, each with its covariance, the last
    # frame's pose uncertain too (frontend/pose_filter.py); with a stereo camera whose map points
    # are weighed by their covariances (``tracking.localization_point_max_sigma_m``), else as
    # "exact_points": optimised again with the VO points taken as exact in the world (ORB-SLAM2),
    # which holds each frame to the last one's pose as if that were exact (benchmarks/saved_maps.md).
    fusion: Literal["filter", "exact_points"] = "filter"
    # The filter's innovation test: a pose from the map further from the odometry's prediction than
    # this squared Mahalanobis distance (unitless, 6 dof; 22.46 is chi2's 99.9%) replaces it
    # rather than being averaged with it.
    filter_max_chi2: float = 22.46
    # The filter's weight on the map: the information of a pose from the map (pixel noise and the
    # points' covariances) is multiplied by this (unitless, 1: as computed). The map's points share
    # their errors (the same keyframes placed them), which the covariances, taken independent, leave
    # out, so the map poses' errors exceed the standard deviations their information gives, and a
    # weight below 1 trusts the map as much as its errors warrant (benchmarks/saved_maps.md).
    filter_map_information_scale: float = 0.25

    def __post_init__(self) -> None:
        problems = []
        if not self.filter_max_chi2 > 0:
            problems.append(f"filter_max_chi2={self.filter_max_chi2} must be > 0 (inf: no test)")
        if not (math.isfinite(self.filter_map_information_scale) and self.filter_map_information_scale > 0):
            problems.append(f"filter_map_information_scale={self.filter_map_information_scale} must be a finite number > 0")
        if problems:
            raise ConfigError("invalid frontend tracking.visual_odometry configuration: " + "; ".join(problems))


@dataclass(frozen=True)
class OdometryPose:
    """A frame placed against the last frame's map and VO points."""

    T_cam_world: np.ndarray  # (4, 4)
    rows: np.ndarray  # (N,) int64 map row of each keypoint matched to a map point (inliers), -1 none
    n_map: int  # inlier matches to map points
    n_total: int  # inlier matches to map and VO points
    vo_keypoints: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # (V,) keypoints on VO points
    vo_p_world: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (V, 3) those points, metres

    def is_vo(self, config: VisualOdometryConfig) -> bool:
        return self.n_map < config.min_map_matches


@dataclass(frozen=True)
class LastFramePoints:
    """The points of the last frame to match: map points (``rows`` >= 0) then VO points (-1)."""

    keypoints: np.ndarray  # (M,) int64 keypoint of the last frame
    p_world: np.ndarray  # (M, 3) metres
    descriptors: np.ndarray  # (M, 32) uint8
    rows: np.ndarray  # (M,) int64 map row, -1 for a VO point
    T_cam_world_last: np.ndarray  # (4, 4) the last frame's pose the VO points were made with


def last_frame_points(
    last: Frame, last_rows: np.ndarray, T_cam_world_last: np.ndarray, map_p_world: np.ndarray,
    map_descriptors: np.ndarray, map_valid: np.ndarray, close_depth_m: float, max_points: int,
) -> LastFramePoints:
    """The last frame's valid map points and VO points made from its depths: every keypoint with a
    depth and no valid map point nearer than ``close_depth_m`` (metres), and at least the nearest
    ``max_points`` of them (0 and a negative ``close_depth_m``: no VO point)."""
    with_map = np.flatnonzero(last_rows >= 0)
    with_map = with_map[map_valid[last_rows[with_map]]]
    rows = last_rows[with_map]
    free = np.flatnonzero((last.depth_m > 0) & ~np.isin(np.arange(len(last_rows)), with_map))
    free = free[np.argsort(last.depth_m[free], kind="stable")]
    n_close = int(np.count_nonzero(last.depth_m[free] <= close_depth_m))
    vo = free[: max(n_close, min(max_points, len(free)))]
    vo_world = unproject_keypoints(last.features.px[vo], last.depth_m[vo], last.calibration, invert_T(T_cam_world_last))
    return LastFramePoints(
        keypoints=np.concatenate([with_map, vo]).astype(np.int64),
        p_world=np.vstack([map_p_world[rows].reshape(-1, 3), vo_world]),
        descriptors=np.vstack([map_descriptors[rows].reshape(-1, 32), last.features.descriptors[vo]]),
        rows=np.concatenate([rows, np.full(len(vo), -1, dtype=np.int64)]),
        T_cam_world_last=np.asarray(T_cam_world_last, dtype=float),
    )


@dataclass(frozen=True)
class LastFrameSearch:
    """ORB-SLAM2's motion-model search of the last frame's points in the current frame."""

    radius_px: float  # window half-width at level 0 (pixels, times the level's scale factor)
    wide_factor: float  # window multiplier of the retry when fewer than min_matches matched
    min_matches: int  # fewer matches after the retry: no pose
    max_distance: int  # Hamming bits (ORB-SLAM's TH_HIGH)
    check_orientation: bool  # keep only matches in the 3 dominant rotation-histogram bins


def track_last_frame(
    frame: Frame, last: Frame, points: LastFramePoints, T_predicted: np.ndarray, search: LastFrameSearch,
    pose_config: PoseOptimizerConfig, point_covariance: np.ndarray | None = None,
) -> OdometryPose | None:
    """Match ``points`` into ``frame`` around their projection with ``T_predicted`` (T_cam_world),
    optimise the pose and keep the inliers; None with fewer than ``search.min_matches`` matches.
    The caller judges the inlier counts. ``point_covariance``: (M, 3, 3) of ``points``, to weigh
    them by (``optimize_pose``); None: exact."""
    match = _match(frame, last, points, T_predicted, search.radius_px, search)
    if np.count_nonzero(match >= 0) < search.min_matches:
        match = _match(frame, last, points, T_predicted, search.wide_factor * search.radius_px, search)
    kps = np.flatnonzero(match >= 0)
    if len(kps) < search.min_matches:
        return None
    covariance = None if point_covariance is None else point_covariance[match[kps]]
    result = optimize_frame_pose(frame, T_predicted, kps, points.p_world[match[kps]], pose_config, point_covariance=covariance)
    inliers = kps[result.inliers]
    rows = np.full(len(frame.features), -1, dtype=np.int64)
    rows[inliers] = points.rows[match[inliers]]
    on_vo = inliers[points.rows[match[inliers]] < 0]
    return OdometryPose(
        result.T_cam_world, rows, int(np.count_nonzero(rows >= 0)), len(inliers), on_vo, points.p_world[match[on_vo]]
    )


def optimise_with_odometry(
    frame: Frame, T_init: np.ndarray, map_keypoints: np.ndarray, map_p_world: np.ndarray, odometry: OdometryPose,
    pose_config: PoseOptimizerConfig, map_covariance: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The pose from the map matches (keypoints ``map_keypoints`` on points ``map_p_world``) and the
    odometry's VO matches on other keypoints together: (T_cam_world, inlier mask over ``map_keypoints``).
    ``map_covariance``: (K, 3, 3) of the map points, to weigh them by; the VO points are exact."""
    free = ~np.isin(odometry.vo_keypoints, map_keypoints)
    kps = np.concatenate([map_keypoints, odometry.vo_keypoints[free]]).astype(np.int64)
    p_world = np.vstack([np.asarray(map_p_world).reshape(-1, 3), odometry.vo_p_world[free]])
    covariance = None
    if map_covariance is not None:
        covariance = np.zeros((len(kps), 3, 3))
        covariance[: len(map_keypoints)] = map_covariance
    result = optimize_frame_pose(frame, T_init, kps, p_world, pose_config, point_covariance=covariance)
    return result.T_cam_world, np.asarray(result.inliers[: len(map_keypoints)], dtype=bool)


def _match(frame: Frame, last: Frame, points: LastFramePoints, T_predicted, radius_px: float, search: LastFrameSearch) -> np.ndarray:
    """(N,) index into ``points`` of each keypoint of ``frame`` matched, -1 none (ORB-SLAM2's
    ``SearchByProjection`` of a frame in the last one)."""
    cal: PinholeCalibration = frame.calibration
    feats, last_feats = frame.features, last.features
    p_cam = points.p_world @ T_predicted[:3, :3].T + T_predicted[:3, 3]
    z = p_cam[:, 2]
    safe_z = np.where(z > 1e-9, z, 1e-9)
    u, v = cal.fx * p_cam[:, 0] / safe_z + cal.cx, cal.fy * p_cam[:, 1] / safe_z + cal.cy
    idx = np.flatnonzero((z > 0) & (u >= 0) & (u < cal.width) & (v >= 0) & (v < cal.height))
    # Moving forward by more than a baseline, points get nearer and appear on the same or coarser
    # levels; moving backward, on the same or finer ones (ORB-SLAM2).
    T_last_cur = points.T_cam_world_last @ invert_T(T_predicted)
    baseline = cal.baseline_m or 0.0
    forward, backward = T_last_cur[2, 3] > baseline, -T_last_cur[2, 3] > baseline
    min_off, max_off = (0, None) if forward else (None, 0) if backward else (-1, 1)
    levels = last_feats.level[points.keypoints[idx]].astype(np.int64)
    found = search_by_projection(
        np.column_stack([u, v])[idx], levels, points.descriptors[idx], feats.px, feats.level, feats.descriptors,
        radius_px * feats.scale_factors[levels], max_distance=search.max_distance, ratio=None, min_level_offset=min_off,
        max_level_offset=max_off, kp_right_u=frame.right_u,
        proj_right_u=(u - cal.bf / safe_z)[idx] if cal.baseline_m is not None else None,
    )  # fmt: skip
    hit = found >= 0
    matched_kps, source = found[hit].astype(np.int64), idx[hit]
    if search.check_orientation and len(matched_kps):
        keep = rotation_consistent(last_feats.angle_deg[points.keypoints[source]] - feats.angle_deg[matched_kps])
        matched_kps, source = matched_kps[keep], source[keep]
    out = np.full(len(feats), -1, dtype=np.int64)
    out[matched_kps] = source
    return out
