"""The tracker's configuration: ORB-SLAM2's tracking thresholds, the local map cache's settings,
saved maps and localisation mode."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from zenslam.errors import ConfigError
from zenslam.frontend.local_map import LocalMapConfig
from zenslam.frontend.monocular_initialisation import MonocularInitialisationConfig
from zenslam.frontend.relocalisation import RelocalisationConfig
from zenslam.frontend.visual_odometry import VisualOdometryConfig


@dataclass(frozen=True)
class TrackingConfig:
    """Tracking thresholds (ORB-SLAM2's defaults unless noted) and the local map's settings."""

    # ORB-SLAM2 starts a stereo/RGB-D map on a frame with > 500 keypoints (all of them, not only those
    # with depth) and makes a point of each depth; the depth floor only guards against empty maps.
    min_init_keypoints: int = 500  # keypoints in the frame needed to initialise a map
    min_init_depth_points: int = 100  # keypoints with depth needed to initialise a map
    motion_radius_px: float = 15.0  # motion-model search window (pixels at level 0, x level scale)
    motion_min_matches: int = 20  # fewer matches: retry with a wider window, then give up
    motion_wide_factor: float = 2.0  # window multiplier of the retry
    max_descriptor_distance: int = 100  # Hamming bits, ORB-SLAM's TH_HIGH (projection searches)
    reference_max_distance: int = 50  # Hamming bits, ORB-SLAM's TH_LOW (reference keyframe matching)
    reference_ratio: float = 0.7  # best / second-best distance ratio (reference keyframe matching)
    reference_min_matches: int = 15  # descriptor matches needed to try the reference keyframe pose
    check_orientation: bool = True  # keep only matches in the 3 dominant rotation-histogram bins
    min_pose_inliers: int = 10  # inliers needed after motion-model / reference tracking
    local_radius_stereo: float = 1.0  # local-map search window factor for stereo (ORB-SLAM th)
    local_radius_rgbd: float = 3.0  # the same for RGB-D
    local_ratio: float = 0.8  # best / second-best ratio in the local-map search (same level only)
    min_view_cos: float = 0.5  # cos of the largest angle to a point's mean viewing direction
    min_local_map_inliers: int = 30  # inliers needed after local-map tracking
    # A keyframe gets new points at its unmatched keypoints nearer than this many baselines, and
    # for at least the nearest ``new_points_min`` keypoints. ORB-SLAM2 stops at its close-point
    # limit (35 baselines) and leaves farther points to local mapping's triangulation; a frontend
    # that also tracks without mapping needs some farther points of its own, hence more than 35.
    new_points_depth_baselines: float = 60.0
    new_points_min: int = 100  # keypoints (with or without a point) visited nearest first at a keyframe
    # The keyframe decision compares the inliers with the reference keyframe's points seen by at
    # least this many keyframes. ORB-SLAM2 uses 2 once the map has 3 keyframes, relying on local
    # mapping to give new points their second observation quickly. 1 keeps tracking dense
    # without that, at the cost of more keyframes: with new points limited to fewer baselines 2
    # can lose tracking; at the default ``new_points_depth_baselines`` 2 tracks as well.
    reference_min_observations: int = 1
    reinit_after_lost_frames: int = 10  # consecutive frames without a pose before starting over (0 = never)
    # The backend starts from a saved map (``zenslam run --map``): no new map is started; frames stay
    # lost until one relocalises into the saved one, and whenever the reference keyframe becomes a
    # keyframe of that map (an id below ``local_map.keyframe_id_start``) its window is fetched from
    # the backend into the cache, which holds only what tracking has come to.
    start_in_map: bool = False
    # ORB-SLAM's localisation mode (mbOnlyTracking): no keyframe and no point is made, frames are only
    # placed in the backend's map; with few map matches they go on by visual odometry (see
    # visual_odometry) until a relocalisation finds the map again. Lost frames are never started over.
    localization: bool = False
    # Localisation mode with a stereo camera, not ORB-SLAM's: each map point is weighed by its
    # position's covariance from the saved keyframes that observe it (frontend/point_uncertainty.py),
    # bounded at this standard deviation (metres), so a far point's depth error, seen from the side,
    # does not move the pose as if it were exact. None: every point exact, as ORB-SLAM. An RGB-D or
    # monocular camera keeps its points exact: a depth sensor's depths are far better than the
    # pixel model of the virtual right image says, and there the weighing made localisation
    # worse (benchmarks/saved_maps.md); monocular is not measured.
    localization_point_max_sigma_m: float | None = 10.0
    visual_odometry: VisualOdometryConfig = field(default_factory=VisualOdometryConfig)
    monocular: MonocularInitialisationConfig = field(default_factory=MonocularInitialisationConfig)
    local_map: LocalMapConfig = field(default_factory=LocalMapConfig)
    relocalisation: RelocalisationConfig = field(default_factory=RelocalisationConfig)

    def __post_init__(self) -> None:
        sigma = self.localization_point_max_sigma_m
        if sigma is not None and not (math.isfinite(sigma) and sigma > 0):
            raise ConfigError(
                f"frontend tracking.localization_point_max_sigma_m={sigma} must be a finite distance > 0 m (or null: points exact)"
            )
