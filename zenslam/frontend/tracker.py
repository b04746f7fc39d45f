"""Frame-to-map tracking for stereo, RGB-D and monocular cameras: ORB-SLAM2's Tracking.

Per frame: predict the pose with the constant-velocity model and match the last frame's points
by projection (falling back to descriptor matching against the reference keyframe), optimise the
pose, then track the local map (points of the keyframes covisible with the frame) and optimise
again; finally decide whether the frame becomes a keyframe, which creates new points from its
stereo/RGB-D depths (a monocular keyframe makes none: local mapping triangulates them).

A stereo/RGB-D map starts on one frame's depths. A monocular map starts on two frames: the first
frame with enough parallax to a reference frame (``monocular_initialisation``) becomes the
second keyframe, the reference the first, and both are made at that frame's step (the reference
one in ``TrackResult.earlier_keyframes``); until then frames report ``initializing`` with a
reason such as ``waiting_for_parallax``.

Lost frames: a lost frame reports ``lost`` with a reason. With a vocabulary and a source of
candidates (the backend's keyframe database, passed to ``track``), every following frame is
relocalised, as ORB-SLAM does: its bag of words is sent to the source, the candidate keyframes
that come back are matched (``relocalisation.relocalise``), the matched keyframe and its covisible
neighbours re-enter the cache, the local map is tracked and the motion model restarts; the frame
reports ``ok`` with ``relocalised``. Without them, the next frame tries the reference keyframe and
the last good pose again. After ``reinit_after_lost_frames`` consecutive frames without a pose
the tracker starts over from the current frame at the last good pose (a new keyframe with fresh
points, not connected to the old ones), reported as ``initializing``.

Localisation mode (``localization``): frames with few map matches go on by visual odometry and try
to relocalise at every frame; a relocalisation is taken only near the odometry's pose
(``relocalisation.vo_agreement_*``), unless the odometry failed too. With a stereo camera the saved
map's points are weighed by their covariance from the keyframes the cache holds (``point_uncertainty``).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections import Counter
from dataclasses import dataclass, field
from collections.abc import Callable
from typing import Literal

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ConfigError
from zenslam.frontend.feature_matcher import match_by_descriptor, rotation_consistent, search_by_projection
from zenslam.frontend.cache_eviction import CacheEviction
from zenslam.frontend.frame import Frame, frame_pose_information, optimize_frame_pose
from zenslam.frontend.keyframe import KeyFrame, select_new_point_keypoints, unproject_keypoints
from zenslam.frontend.keyframe_decision import (
    KeyframeDecisionConfig,
    KeyframeDecisionInputs,
    close_depth_threshold_m,
    close_point_counts,
    need_new_keyframe,
)
from zenslam.frontend.frustum import project_in_frustum
from zenslam.frontend.local_map import LocalMap, LocalMapConfig
from zenslam.frontend.monocular_initialisation import InitialMap, MonocularInitialisationConfig, MonocularInitialiser
from zenslam.frontend.motion_model import ConstantVelocityModel
from zenslam.frontend.point_uncertainty import point_covariances, view_information
from zenslam.frontend.pose_filter import PoseEstimate, fuse, predict
from zenslam.pose_optimizer import PoseOptimizerConfig
from zenslam.frontend.relocalisation import BowTransform, PosePrior, RelocalisationConfig, keyframes_to_restore, pose_offset, relocalise
from zenslam.frontend.visual_odometry import (
    LastFrameSearch,
    OdometryPose,
    VisualOdometryConfig,
    last_frame_points,
    optimise_with_odometry,
    track_last_frame,
)
from zenslam.geometry import invert_T, transform_points
from zenslam.map_point_rules import radius_by_viewing_cos
from zenslam.schemas.map_update import MapUpdate
from zenslam.schemas.relocalisation import RelocalisationCandidates, RelocalisationQuery

logger = logging.getLogger(__name__)

TrackingState = Literal["ok", "lost", "initializing"]
# Asks the backend for relocalisation candidates; None when it did not answer.
CandidateSource = Callable[[RelocalisationQuery], "RelocalisationCandidates | None"]


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
    # without that (it still tracks the synthetic loop with 45-baseline points, where 2 loses
    # it) at 3-4x the keyframes; 2 also tracks every scene here at the default 60 baselines.
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
    # pixel model of the virtual right image says, and there the weighing measured worse
    # (benchmarks/README.md, "Saved maps and localisation"); monocular is not measured.
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


@dataclass(frozen=True)
class TrackResult:
    """What tracking one frame produced."""

    state: TrackingState
    lost_reason: str | None
    T_world_cam: np.ndarray | None  # (4, 4) camera -> world, None when lost
    n_tracked: int  # inlier matches to map points
    keyframe: KeyFrame | None  # the keyframe made from this frame
    timings_ms: dict[str, float]  # motion_model_tracking, local_map_tracking, pose_optimization, keyframe_decision
    # With a pose: ORB-SLAM's reference keyframe (the frame's own keyframe if it made one), -1 none,
    # and the camera in that keyframe's frame (4, 4), so the pose can follow the keyframe's corrections.
    reference_keyframe_id: int = -1
    T_reference_cam: np.ndarray | None = None
    relocalised: bool = False  # the frame found the map again after tracking was lost (or, localising, on visual odometry)
    # Keyframes made at this step from earlier frames, to be sent before ``keyframe``: a monocular
    # map's first keyframe (its reference frame), made when the second one is.
    earlier_keyframes: tuple[KeyFrame, ...] = ()


@dataclass
class _LastFrame:
    frame: Frame
    rows: np.ndarray  # (N,) map point row per keypoint, -1 none
    T_cam_world: np.ndarray
    # (6, 6) of T_cam_world (``pose_filter``) where localisation filters the poses; None: exact
    covariance: np.ndarray | None = None

    def estimate(self) -> PoseEstimate:
        """The frame's pose and covariance (zeros when it has none: taken as exact)."""
        return PoseEstimate(self.T_cam_world, np.zeros((6, 6)) if self.covariance is None else self.covariance)


class Tracker:
    """Tracks frames of one stereo, RGB-D or monocular camera against the frontend's local map."""

    def __init__(
        self,
        calibration: PinholeCalibration,
        sensor: SensorKind,
        config: TrackingConfig | None = None,
        pose_config: PoseOptimizerConfig | None = None,
        keyframe_config: KeyframeDecisionConfig | None = None,
        camera_fps: float = 10.0,
        vocabulary: BowTransform | None = None,
    ) -> None:
        self.calibration = calibration
        self.sensor = sensor
        self.config = config or TrackingConfig()
        self.pose_config = pose_config or PoseOptimizerConfig()
        self.keyframe_config = keyframe_config or KeyframeDecisionConfig()
        self.camera_fps = camera_fps
        self.map = LocalMap(self.config.local_map)
        self.eviction = CacheEviction(self.map)
        self.motion = ConstantVelocityModel()
        self._monocular = MonocularInitialiser(self.config.monocular) if sensor == "mono" else None
        self.th_depth_m = close_depth_threshold_m(calibration.baseline_m or 0.0, self.keyframe_config)
        self.lost_reasons: Counter[str] = Counter()
        self.n_reinitialisations = 0
        self.n_relocalisations = 0
        self.vocabulary = vocabulary  # the bag-of-words vocabulary relocalisation queries and matches with
        self._relocalised_at = -(1 << 62)  # frame index of the last relocalisation
        self._last: _LastFrame | None = None  # the last successfully tracked frame
        self._reference_slot = -1
        self._last_keyframe_index = -1
        self._lost_streak = 0
        self._timers: dict[str, float] = {}
        self._on_vo = False  # localisation mode: the last frame was placed by visual odometry
        # Localisation mode: the frame whose VO points frames on visual odometry are matched to, the
        # VO matches of the first frame matched to it (0 before that), and whether the odometry of
        # the frame being tracked came from it.
        self._vo_anchor: _LastFrame | None = None
        self._vo_anchor_matches = 0
        self._odometry_from_anchor = False
        self._window_of = -1  # the saved keyframe whose window was fetched last
        self.n_vo_frames = 0  # localisation mode: frames placed by visual odometry
        self._vo_path_m = 0.0  # localisation mode: the camera's path on visual odometry since the map was last tracked

    @property
    def starting_map(self) -> bool:
        """The next frame may start a map: none exists yet, or tracking was lost long enough to start over."""
        if self._last is None:
            return not self.config.start_in_map
        reinit = self.config.reinit_after_lost_frames
        return bool(reinit and self._lost_streak >= reinit) and not self.config.localization

    @property
    def last_frame(self) -> _LastFrame | None:
        """The last frame tracked (with the map-point row of each keypoint), None before the first."""
        return self._last

    @property
    def may_ask_backend(self) -> bool:
        """Whether tracking the next frame may ask the backend for relocalisation candidates or a
        tracking window: tracking is lost, or the run enters or localises in a saved map."""
        return self._lost_streak > 0 or self.config.start_in_map or self.config.localization

    # ---- the per-frame entry point ----------------------------------------------------------------
    def track(self, frame: Frame, keyframes_in_flight: int = 0, candidates: CandidateSource | None = None) -> TrackResult:
        """Track one frame: its pose in the world, the inlier count, a keyframe when one is made, and
        the pose relative to the frame's reference keyframe.

        ``keyframes_in_flight`` counts keyframes sent to local mapping whose update has not been
        applied (the keyframe decision's view of local mapping; 0 = idle). ``candidates`` asks the
        backend for relocalisation candidates; it is called only while tracking is lost.
        """
        result = self._track(frame, keyframes_in_flight, candidates)
        if result.T_world_cam is not None and self.config.start_in_map and candidates is not None:
            self._fetch_window(frame, candidates, keyframes_in_flight + (result.keyframe is not None))
            if "map_window" in self._timers:
                result = dataclasses.replace(result, timings_ms={**result.timings_ms, "map_window": self._timers["map_window"]})
        reference = self.map.keyframe(self._reference_slot) if self._reference_slot >= 0 else None
        if result.T_world_cam is None or reference is None:
            return result
        return dataclasses.replace(
            result, reference_keyframe_id=int(reference.id), T_reference_cam=reference.T_cam_world @ result.T_world_cam
        )

    def _track(self, frame: Frame, keyframes_in_flight: int, candidates: CandidateSource | None) -> TrackResult:
        self._timers = dict.fromkeys(
            ("motion_model_tracking", "local_map_tracking", "pose_optimization", "keyframe_decision"), 0.0
        )
        if self._last is None and self.config.start_in_map:
            return self._enter_map(frame, keyframes_in_flight, candidates)
        if self._last is None:
            return self._start_map(frame, np.eye(4), "no_depth_points_for_init")
        if self.config.localization and self._lost_streak == 0:
            return self._track_localization(frame, candidates)
        relocalising = self._lost_streak > 0 and self._relocalises(candidates)
        failure = None
        if relocalising:
            found, failure = self._relocalise(frame, candidates)
            if found is not None:
                return self._tracked(frame, *found, keyframes_in_flight, relocalised=True)
        if self.starting_map:
            n_lost = self._lost_streak
            result = self._start_map(frame, invert_T(self._last.T_cam_world), "no_depth_points_for_reinit")
            if result.state == "ok":
                self.n_reinitialisations += 1
                logger.warning("tracking restarted at frame %d after %d lost frames", frame.index, n_lost)
                return dataclasses.replace(result, state="initializing")
            return result
        if relocalising:
            return self._lost(frame, failure, 0)
        start, pose_ms = time.perf_counter(), self._timers["pose_optimization"]
        first = self._track_last_frame_or_reference(frame)
        self._add_time("motion_model_tracking", start, pose_ms)
        if first is None:
            return self._lost(frame, "too_few_matches_motion_model_and_reference", 0)
        start, pose_ms = time.perf_counter(), self._timers["pose_optimization"]
        T_cam_world, rows, n_inliers = self._track_local_map(frame, first.T_cam_world, first.rows)
        self._add_time("local_map_tracking", start, pose_ms)
        min_inliers = self._min_local_map_inliers(frame)
        if n_inliers < min_inliers:
            return self._lost(frame, f"local_map_inliers_below_{min_inliers}", n_inliers)
        return self._tracked(frame, T_cam_world, rows, n_inliers, keyframes_in_flight)

    def _tracked(
        self, frame: Frame, T_cam_world: np.ndarray, rows: np.ndarray, n_inliers: int, keyframes_in_flight: int,
        relocalised: bool = False, covariance: np.ndarray | None = None,
    ) -> TrackResult:
        """A frame tracked in the local map: the keyframe decision, the motion model (restarted after
        a relocalisation, as ORB-SLAM's has no velocity across a lost frame) and the last frame,
        with the pose's ``covariance`` where localisation filters the poses (None: the map
        inliers' alone)."""
        start = time.perf_counter()
        keyframe = None
        if self._need_keyframe(frame, rows, n_inliers, keyframes_in_flight):
            keyframe = self._make_keyframe(frame, T_cam_world, rows)
        self._timers["keyframe_decision"] += (time.perf_counter() - start) * 1e3
        if relocalised:
            self.motion.reset()
        else:
            self.motion.update(self._last.T_cam_world, T_cam_world, self._frame_gap(frame), self._elapsed_ns(frame))
        if covariance is None and self._filters_poses:
            covariance = PoseEstimate.from_information(T_cam_world, self._map_information(frame, T_cam_world, rows)).covariance
        self._last = _LastFrame(frame, rows, T_cam_world, covariance)
        self._lost_streak = 0
        self._on_vo = False
        self._vo_anchor = None
        self._vo_path_m = 0.0
        if keyframe is not None:
            self._evict(keyframes_in_flight + 1)
        return TrackResult("ok", None, invert_T(T_cam_world), n_inliers, keyframe, dict(self._timers), relocalised=relocalised)

    def apply_map_update(self, update: MapUpdate) -> None:
        """Apply the backend's correction to the local map and keep the last frame where it was
        relative to its reference keyframe (ORB-SLAM2's UpdateLastFrame), so the motion model
        predicts in the corrected map."""
        reference = self.map.keyframe(self._reference_slot) if self._reference_slot >= 0 else None
        T_last_ref = None
        if self._last is not None and reference is not None:
            T_last_ref = self._last.T_cam_world @ reference.T_world_cam
        self.map.apply_map_update(update)
        reference = self.map.keyframe(self._reference_slot) if self._reference_slot >= 0 else None
        if T_last_ref is not None and reference is not None:
            before = invert_T(self._last.T_cam_world)[:3, 3]
            self._last.T_cam_world = T_last_ref @ reference.T_cam_world
            logger.debug(
                "map update of keyframe %d (%s) applied after frame %d: last frame moved %.3f m (reference keyframe %d)",
                update.keyframe_id, update.kind, self._last.frame.index,
                float(np.linalg.norm(invert_T(self._last.T_cam_world)[:3, 3] - before)), reference.id,
            )  # fmt: skip

    def _evict(self, unanswered: int, force: bool = False) -> None:
        """Evict the map cache when due (or ``force``), around the last frame's window; ``unanswered``
        newest keyframes (the backend's updates of them not applied yet) stay. Remaps the slots and
        rows the tracker holds."""
        last = self._last
        eviction = self.eviction.maybe_evict(last.rows, self._reference_slot, unanswered, keep_rows=last.rows, force=force)
        if eviction is None:
            return
        last.rows = np.where(last.rows >= 0, eviction.row_map[last.rows], -1)
        self._reference_slot = int(eviction.slot_map[self._reference_slot]) if self._reference_slot >= 0 else -1

    def _add_time(self, key: str, start: float, pose_ms_at_start: float) -> None:
        """Charge the time since ``start`` to ``key``, less the pose optimisation done meanwhile."""
        pose_ms = self._timers["pose_optimization"] - pose_ms_at_start
        self._timers[key] += (time.perf_counter() - start) * 1e3 - pose_ms

    def _optimize(self, T_cam_world: np.ndarray, frame: Frame, rows: np.ndarray):
        """Pose optimisation of ``frame`` matched to map rows (N,) -1 none; returns (T, inlier mask (N,))."""
        start = time.perf_counter()
        kps = np.flatnonzero(rows >= 0)
        result = optimize_frame_pose(
            frame, T_cam_world, kps, self.map.p_world[rows[kps]], self.pose_config, point_covariance=self._covariance(rows[kps])
        )
        inliers = np.zeros(len(rows), dtype=bool)
        inliers[kps] = result.inliers
        self._timers["pose_optimization"] += (time.perf_counter() - start) * 1e3
        return result.T_cam_world, inliers

    # ---- initialisation and loss ----------------------------------------------------------------
    def _start_map(self, frame: Frame, T_world_cam: np.ndarray, reason: str) -> TrackResult:
        """A new map at ``T_world_cam``: from this frame's depths, or for a monocular camera from two frames."""
        if self._monocular is None:
            return self._initialise(frame, T_world_cam, reason)
        found = self._monocular.try_frame(frame)
        if isinstance(found, str):
            self.lost_reasons[found] += 1
            self._lost_streak += 1
            return TrackResult("initializing", found, None, 0, None, dict(self._timers))
        return self._initialise_monocular(found, T_world_cam)

    def _initialise_monocular(self, found: InitialMap, T_world_ref: np.ndarray) -> TrackResult:
        """The two keyframes of a monocular map: the reference at ``T_world_ref`` with the triangulated
        points, then the current frame observing them."""
        start = time.perf_counter()
        reference, current = found.reference, found.current
        ref_rows = np.full(reference.n_keypoints, -1, dtype=np.int64)
        first = self._make_keyframe(
            reference, invert_T(T_world_ref), ref_rows, found.reference_keypoints, transform_points(T_world_ref, found.p_ref)
        )
        T_cam_world = found.T_cur_ref @ invert_T(T_world_ref)
        rows = np.full(current.n_keypoints, -1, dtype=np.int64)
        rows[found.current_keypoints] = ref_rows[found.reference_keypoints]
        second = self._make_keyframe(current, T_cam_world, rows, np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
        self._timers["keyframe_decision"] += (time.perf_counter() - start) * 1e3
        self.motion.reset()
        self._last = _LastFrame(current, rows, T_cam_world)
        self._lost_streak = 0
        n_points = len(found.reference_keypoints)
        logger.info(
            "monocular map initialised at frames %d and %d (%s, parallax %.1f deg) with %d points",
            reference.index, current.index, found.model, found.parallax_deg, n_points,
        )  # fmt: skip
        return TrackResult(
            "ok", None, invert_T(T_cam_world), n_points, second, dict(self._timers), earlier_keyframes=(first,)
        )

    def _initialise(self, frame: Frame, T_world_cam: np.ndarray, reason: str) -> TrackResult:
        """A new map from one frame's depths at ``T_world_cam``: one keyframe, a point per depth."""
        n_depth = int(np.count_nonzero(frame.depth_m > 0))
        if len(frame.features) <= self.config.min_init_keypoints or n_depth < self.config.min_init_depth_points:
            self.lost_reasons[reason] += 1
            self._lost_streak += 1
            return TrackResult("initializing", reason, None, 0, None, dict(self._timers))
        start = time.perf_counter()
        rows = np.full(len(frame.features), -1, dtype=np.int64)
        new_kps = np.flatnonzero(frame.depth_m > 0)
        T_cam_world = invert_T(T_world_cam)
        keyframe = self._make_keyframe(frame, T_cam_world, rows, new_kps)
        self._timers["keyframe_decision"] += (time.perf_counter() - start) * 1e3
        self.motion.reset()
        self._last = _LastFrame(frame, rows, T_cam_world)
        self._lost_streak = 0
        logger.info("map initialised at frame %d with %d points", frame.index, len(new_kps))
        T_world_cam = np.asarray(T_world_cam, dtype=float).copy()
        return TrackResult("ok", None, T_world_cam, len(new_kps), keyframe, dict(self._timers))

    def _lost(self, frame: Frame, reason: str, n_tracked: int) -> TrackResult:
        self.lost_reasons[reason] += 1
        self._lost_streak += 1
        self.motion.reset()
        logger.debug("frame %d lost: %s", frame.index, reason)
        return TrackResult("lost", reason, None, n_tracked, None, dict(self._timers))

    # ---- a saved map, and localisation mode -----------------------------------------------------------
    def _enter_map(self, frame: Frame, keyframes_in_flight: int, candidates: CandidateSource | None) -> TrackResult:
        """Before the first pose in a saved map: relocalise into it, or stay lost."""
        if not self._relocalises(candidates):
            return self._lost(frame, "no_relocalisation_into_the_saved_map", 0)
        found, failure = self._relocalise(frame, candidates)
        if found is None:
            return self._lost(frame, failure, 0)
        return self._tracked(frame, *found, keyframes_in_flight, relocalised=True)

    def _track_localization(self, frame: Frame, candidates: CandidateSource | None) -> TrackResult:
        """ORB-SLAM2's Track with mbOnlyTracking: the motion model with the last frame's map and VO
        points; a frame with enough map matches then tracks the local map (no keyframe). A frame on
        visual odometry, or whose local-map tracking fails while its odometry holds, keeps the
        odometry pose; the next frames also try to relocalise, and the first that does leaves VO."""
        start, pose_ms = time.perf_counter(), self._timers["pose_optimization"]
        odometry = self._track_odometry(frame)
        self._add_time("motion_model_tracking", start, pose_ms)
        if self._on_vo and self._relocalises(candidates):
            found, _ = self._relocalise(frame, candidates, self._odometry_prior(odometry))
            if found is not None:
                T_cam_world, rows, n_inliers, covariance = self._relocalised_with_odometry(frame, found, odometry)
                return self._tracked(frame, T_cam_world, rows, n_inliers, 0, relocalised=True, covariance=covariance)
        if odometry is None and not self._on_vo:
            start, pose_ms = time.perf_counter(), self._timers["pose_optimization"]
            odometry = self._track_reference_keyframe(frame)
            self._add_time("motion_model_tracking", start, pose_ms)
        if odometry is None:
            return self._lost(frame, "too_few_matches_visual_odometry" if self._on_vo else "too_few_matches_motion_model_and_reference", 0)
        if not self._on_vo and not odometry.is_vo(self.config.visual_odometry):
            start, pose_ms = time.perf_counter(), self._timers["pose_optimization"]
            T_cam_world, rows, n_inliers = self._track_local_map(frame, odometry.T_cam_world, odometry.rows)
            joint_below = self.config.visual_odometry.joint_below_map_inliers
            covariance = None
            if (joint_below is None or n_inliers < joint_below) and len(odometry.vo_keypoints):
                T_cam_world, rows, n_inliers, covariance = self._with_odometry(frame, T_cam_world, rows, odometry)
            self._add_time("local_map_tracking", start, pose_ms)
            if n_inliers >= self._min_local_map_inliers(frame):
                return self._tracked(frame, T_cam_world, rows, n_inliers, 0, covariance=covariance)
        if odometry.n_total < self.config.visual_odometry.min_matches:
            return self._lost(frame, f"local_map_inliers_below_{self._min_local_map_inliers(frame)}", odometry.n_total)
        return self._tracked_by_odometry(frame, odometry)

    def _track_odometry(self, frame: Frame) -> OdometryPose | None:
        """The motion model (the last pose when it has no velocity) against the last frame's map and
        VO points, or on visual odometry against the anchor's (the last frame's when the anchor
        gives no pose); None with fewer than ``visual_odometry.min_matches`` inliers."""
        last, min_matches = self._last, self.config.visual_odometry.min_matches
        predicted = self.motion.predict(last.T_cam_world, self._frame_gap(frame))
        T_predicted = last.T_cam_world if predicted is None else predicted
        odometry = None
        anchored = self.config.visual_odometry.anchor_keep_ratio < 1.0
        self._odometry_from_anchor = anchored and self._on_vo and self._vo_anchor is not None
        if self._odometry_from_anchor:
            odometry = self._match_last_frame(frame, T_predicted, True, self._vo_anchor)
            self._odometry_from_anchor = odometry is not None and odometry.n_total >= min_matches
        if not self._odometry_from_anchor:
            odometry = self._match_last_frame(frame, T_predicted, True)
        if odometry is None or odometry.n_total < min_matches:
            return None
        return odometry

    def _with_odometry(self, frame: Frame, T_cam_world: np.ndarray, rows: np.ndarray, odometry: OdometryPose):
        """The local-map pose steadied by the odometry's VO matches: (T, rows, map inliers, covariance).
        ``visual_odometry.fusion`` "filter": fused with the odometry's prediction (``pose_filter``);
        "exact_points": optimised again with the VO matches added as exact points (covariance None)."""
        if self._filters_poses:
            fused = self._fused_with_odometry(frame, T_cam_world, rows, odometry)
            return fused.T_cam_world, rows, int(np.count_nonzero(rows >= 0)), fused.covariance
        start = time.perf_counter()
        kps = np.flatnonzero(rows >= 0)
        T_cam_world, inliers = optimise_with_odometry(
            frame, T_cam_world, kps, self.map.p_world[rows[kps]], odometry, self.pose_config, map_covariance=self._covariance(rows[kps])
        )
        self._timers["pose_optimization"] += (time.perf_counter() - start) * 1e3
        rows = rows.copy()
        rows[kps[~inliers]] = -1
        return T_cam_world, rows, int(np.count_nonzero(inliers)), None

    def _relocalised_with_odometry(self, frame: Frame, found: tuple, odometry: OdometryPose | None):
        """A relocalisation ``found`` (T, rows, map inliers) that ends visual odometry, fused with the
        odometry's prediction where localisation filters the poses: (T, rows, map inliers, covariance)."""
        T_cam_world, rows, n_inliers = found
        if not self._filters_poses or odometry is None or not len(odometry.vo_keypoints):
            return T_cam_world, rows, n_inliers, None
        fused = self._fused_with_odometry(frame, T_cam_world, rows, odometry)
        return fused.T_cam_world, rows, n_inliers, fused.covariance

    def _fused_with_odometry(
        self, frame: Frame, T_cam_world: np.ndarray, rows: np.ndarray, odometry: OdometryPose
    ) -> PoseEstimate:
        """The pose ``T_cam_world`` from the map inliers ``rows`` fused with the odometry's prediction."""
        odometry_config = self.config.visual_odometry
        information = self._map_information(frame, T_cam_world, rows) * odometry_config.filter_map_information_scale
        return fuse(T_cam_world, information, self._odometry_estimate(frame, odometry), odometry_config.filter_max_chi2)

    @property
    def _filters_poses(self) -> bool:
        """``visual_odometry.fusion`` "filter" (``pose_filter``) where the tracker weighs the map's
        points by their covariances (localisation mode, stereo): without them a map pose's
        information is far too confident (an RGB-D camera keeps ORB-SLAM2's exact VO points)."""
        return self._weighs_points and self.config.visual_odometry.fusion == "filter"

    def _map_information(self, frame: Frame, T_cam_world: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(6, 6) information of the pose from the frame's map inliers ``rows``, weighed as tracking
        weighs them."""
        start = time.perf_counter()
        kps = np.flatnonzero(rows >= 0)
        information = frame_pose_information(frame, T_cam_world, kps, self.map.p_world[rows[kps]], self._covariance(rows[kps]))
        self._timers["pose_optimization"] += (time.perf_counter() - start) * 1e3
        return information

    def _odometry_estimate(self, frame: Frame, odometry: OdometryPose) -> PoseEstimate:
        """The frame as its odometry places it relative to the frame whose VO points it matched (the
        anchor or the last frame): the pose from those VO points alone, and the covariance carried
        from that frame plus the odometry's own (``pose_filter.predict``), each VO point weighed by
        the covariance of its one stereo view from that frame (this frame's keypoint's level standing
        for that frame's), bounded as the map's points are."""
        start = time.perf_counter()
        source = self._vo_anchor if self._odometry_from_anchor else self._last
        kps, p_world = odometry.vo_keypoints, odometry.vo_p_world
        levels = frame.features.inv_level_sigma2[frame.features.level[kps]]
        view = view_information(source.T_cam_world, p_world, levels, np.ones(len(kps), dtype=bool), self.calibration)
        covariance = np.linalg.inv(view + np.eye(3) / self.config.localization_point_max_sigma_m**2)
        found = optimize_frame_pose(frame, odometry.T_cam_world, kps, p_world, self.pose_config, point_covariance=covariance)
        T_cam_world, information = odometry.T_cam_world, np.zeros((6, 6))  # no pose: the prediction says nothing
        if found.n_inliers:
            T_cam_world, inliers = found.T_cam_world, found.inliers
            information = frame_pose_information(frame, T_cam_world, kps[inliers], p_world[inliers], covariance[inliers])
        self._timers["pose_optimization"] += (time.perf_counter() - start) * 1e3
        return predict(source.estimate(), T_cam_world, information)

    def _tracked_by_odometry(self, frame: Frame, odometry: OdometryPose) -> TrackResult:
        """A frame placed by visual odometry: the motion model goes on, the map is not touched."""
        self._on_vo = True
        self.n_vo_frames += 1
        self._vo_path_m += pose_offset(self._last.T_cam_world, odometry.T_cam_world)[0]
        covariance = None
        if self._filters_poses:
            covariance = self._odometry_estimate(frame, odometry).covariance
        self._keep_or_move_anchor(frame, odometry, covariance)
        self.motion.update(self._last.T_cam_world, odometry.T_cam_world, self._frame_gap(frame), self._elapsed_ns(frame))
        self._last = _LastFrame(frame, odometry.rows, odometry.T_cam_world, covariance)
        self._lost_streak = 0
        logger.debug("frame %d on visual odometry: %d map, %d total matches", frame.index, odometry.n_map, odometry.n_total)
        T_world_cam = invert_T(odometry.T_cam_world)
        return TrackResult("ok", None, T_world_cam, odometry.n_map, None, dict(self._timers))

    def _odometry_prior(self, odometry: OdometryPose | None) -> PosePrior | None:
        """Where this frame's odometry puts it, and how far a relocalisation may lie from that: the
        configured allowance grown with the path on odometry up to this frame (None: no odometry
        pose, or no check configured)."""
        cfg = self.config.relocalisation
        if odometry is None or cfg.vo_agreement_m is None:
            return None
        path = self._vo_path_m + pose_offset(self._last.T_cam_world, odometry.T_cam_world)[0]
        return PosePrior(
            odometry.T_cam_world, cfg.vo_agreement_m + cfg.vo_agreement_per_m * path, cfg.vo_agreement_deg + cfg.vo_agreement_deg_per_m * path
        )

    def _keep_or_move_anchor(self, frame: Frame, odometry: OdometryPose, covariance: np.ndarray | None) -> None:
        """The frame (its pose's ``covariance``) becomes the VO anchor unless it was matched to the
        anchor and kept enough of it."""
        matches = len(odometry.vo_keypoints)
        if self._odometry_from_anchor and self._vo_anchor_matches == 0:
            self._vo_anchor_matches = matches
        elif not self._odometry_from_anchor or matches < self.config.visual_odometry.anchor_keep_ratio * self._vo_anchor_matches:
            self._vo_anchor = _LastFrame(frame, odometry.rows, odometry.T_cam_world, covariance)
            self._vo_anchor_matches = 0

    def _fetch_window(self, frame: Frame, candidates: CandidateSource, unanswered: int) -> None:
        """With a saved map: when the reference keyframe is a saved one whose window was not fetched
        last, bring its covisible neighbours (the backend's) into the cache, so that local-map
        tracking finds the saved map beyond what relocalisation brought. Restored keyframes pace no
        eviction pass (no keyframe is inserted in localisation mode): past the cache's size by the
        keyframes between passes, a pass runs here (``unanswered``: keyframes sent, not answered)."""
        reference = self.map.keyframe(self._reference_slot) if self._reference_slot >= 0 else None
        if reference is None or reference.id >= self.config.local_map.keyframe_id_start or reference.id == self._window_of:
            return
        self._window_of = int(reference.id)
        started = time.perf_counter()
        cfg = self.config.relocalisation
        empty = np.zeros(0, dtype=np.int64)
        query = RelocalisationQuery(frame.stamp_ns, empty, empty.astype(float), 1, cfg.max_neighbours, window_keyframe_id=int(reference.id))
        reply = candidates(query)
        if reply is not None and reply.candidates:
            self._restore(keyframes_to_restore(reply, int(reference.id)), reply)
        limits = self.config.local_map
        if self.map.n_cached_keyframes > limits.cache_max_keyframes + limits.cache_min_keyframes_between_evictions:
            self._evict(unanswered, force=True)
        self._timers["map_window"] = (time.perf_counter() - started) * 1e3

    def _restore(self, keyframes: list[KeyFrame], reply: RelocalisationCandidates) -> None:
        """Bring the backend's ``keyframes`` (with the reply's points) into the cache; localising,
        estimate the covariance of every point they observe."""
        slots = self.map.restore_keyframes(keyframes, reply.points)
        if not self._weighs_points or not slots:
            return
        rows = np.unique(np.concatenate([self.map.keyframe_point_rows(slot) for slot in slots]))
        self.map.set_covariances(rows, point_covariances(self.map, rows, self.calibration, self.config.localization_point_max_sigma_m))

    @property
    def _weighs_points(self) -> bool:
        """Localisation mode with a stereo camera and ``localization_point_max_sigma_m`` set."""
        return self.config.localization and self.config.localization_point_max_sigma_m is not None and self.sensor == "stereo"

    def _covariance(self, rows: np.ndarray) -> np.ndarray | None:
        """The position covariances (K, 3, 3) of map ``rows`` (K,) to weigh them by in pose
        optimisation; None (points exact) where the tracker does not weigh its points."""
        return self.map.covariance[rows] if self._weighs_points else None

    # ---- relocalisation ------------------------------------------------------------------------------
    def _relocalises(self, candidates: CandidateSource | None) -> bool:
        return candidates is not None and self.vocabulary is not None and self.config.relocalisation.enabled

    def _relocalise(self, frame: Frame, candidates: CandidateSource, prior: PosePrior | None = None) -> tuple[tuple | None, str]:
        """ORB-SLAM2's ``Relocalization`` then ``TrackLocalMap``: ((T_cam_world, rows, inliers), "") on
        success, else (None, why not). The matched keyframe and its neighbours re-enter the cache
        either way. A candidate's pose that ``prior`` does not admit is refused."""
        cfg = self.config.relocalisation
        start, pose_ms = time.perf_counter(), self._timers["pose_optimization"]
        self._timers["relocalisation"] = 0.0
        try:
            if len(frame.features) == 0:
                return None, "relocalisation_no_keypoints"
            bow, fvec = self.vocabulary.transform(frame.features.descriptors)
            query = RelocalisationQuery(frame.stamp_ns, bow.word_ids, bow.weights, cfg.max_candidates, cfg.max_neighbours)
            reply = candidates(query) if len(bow.word_ids) else None
            if reply is None or not reply.candidates:
                return None, "relocalisation_no_candidates"
            found = relocalise(frame, reply, self.vocabulary, cfg, self.pose_config, frame_feature_vector=fvec, prior=prior)
            if found is None:
                return None, "relocalisation_no_candidate_matched"
            self._restore(keyframes_to_restore(reply, found.keyframe_id), reply)
            rows = self.map.rows_of_ids(found.point_ids)
            T_cam_world, rows, n_inliers = self._track_local_map(frame, found.T_cam_world, rows)
        finally:
            self._add_time("relocalisation", start, pose_ms)
        min_inliers = max(self.config.min_local_map_inliers, cfg.min_local_map_inliers_after)
        if n_inliers < min_inliers:
            return None, f"relocalisation_local_map_inliers_below_{min_inliers}"
        self._relocalised_at = frame.index
        self.n_relocalisations += 1
        logger.info("relocalised at frame %d on keyframe %d (%d inliers)", frame.index, found.keyframe_id, n_inliers)
        return (T_cam_world, rows, n_inliers), ""

    def _recently_relocalised(self, frame: Frame) -> bool:
        """Within ORB-SLAM's mMaxFrames (one second of frames) after a relocalisation."""
        window = self.keyframe_config.max_frames or self.camera_fps
        return frame.index < self._relocalised_at + window

    def _min_local_map_inliers(self, frame: Frame) -> int:
        if self._recently_relocalised(frame):
            return max(self.config.min_local_map_inliers, self.config.relocalisation.min_local_map_inliers_after)
        return self.config.min_local_map_inliers

    # ---- stage 1: last frame (motion model) or reference keyframe ---------------------------------
    def _track_last_frame_or_reference(self, frame: Frame) -> OdometryPose | None:
        """The pose from the motion model or the reference keyframe, or None."""
        last = self._last
        predicted = self.motion.predict(last.T_cam_world, self._frame_gap(frame))
        if predicted is not None:
            found = self._track_motion_model(frame, predicted)
            if found is not None:
                return found
        found = self._track_reference_keyframe(frame)
        if found is None and predicted is None:
            found = self._track_motion_model(frame, last.T_cam_world)
        return found

    def _frame_gap(self, frame: Frame) -> int:
        """Frames from the last tracked frame to ``frame`` (1 unless live mode skipped frames), by index
        or, when a source numbers only the frames it passes on, by stamp."""
        return self.motion.frames_between(frame.index - self._last.frame.index, self._elapsed_ns(frame))

    def _elapsed_ns(self, frame: Frame) -> int:
        """Time from the last tracked frame to ``frame``."""
        return frame.stamp_ns - self._last.frame.stamp_ns

    def _track_motion_model(self, frame: Frame, T_predicted: np.ndarray) -> OdometryPose | None:
        """ORB-SLAM2's TrackWithMotionModel: the last frame's points (with its VO points for a
        stereo/RGB-D camera) matched by projection with the predicted pose, the pose optimised; None
        with fewer than ``min_pose_inliers`` map inliers. The VO matches end here: local-map tracking
        starts from the map inliers and this pose."""
        odometry = self._match_last_frame(frame, T_predicted, self.config.visual_odometry.in_slam_mode)
        if odometry is None or odometry.n_map < self.config.min_pose_inliers:
            return None
        return odometry

    def _match_last_frame(
        self, frame: Frame, T_predicted: np.ndarray, with_vo_points: bool, source: _LastFrame | None = None
    ) -> OdometryPose | None:
        """``track_last_frame`` on the valid map points and, ``with_vo_points``, the VO points of the
        last frame (or of ``source``)."""
        last, lm, cfg = source or self._last, self.map, self.config
        close_depth_m, max_points = (self.th_depth_m, cfg.visual_odometry.max_points) if with_vo_points else (-1.0, 0)
        points = last_frame_points(
            last.frame, last.rows, last.T_cam_world, lm.p_world, lm.descriptors, lm.valid, close_depth_m, max_points
        )
        search = LastFrameSearch(
            cfg.motion_radius_px, cfg.motion_wide_factor, cfg.motion_min_matches, cfg.max_descriptor_distance, cfg.check_orientation
        )
        on_map = points.rows >= 0
        map_covariance, covariance = self._covariance(points.rows[on_map]), None
        if map_covariance is not None:  # VO points, made from this camera's own depths, stay exact
            covariance = np.zeros((len(on_map), 3, 3))
            covariance[on_map] = map_covariance
        return track_last_frame(frame, last.frame, points, T_predicted, search, self.pose_config, covariance)

    def _track_reference_keyframe(self, frame: Frame) -> OdometryPose | None:
        """Match the frame to the reference keyframe's points by descriptor; pose from the last frame.

        ORB-SLAM2 matches by bag of words against the keyframe's keypoint descriptors; here a
        brute-force ratio test against the points' representative descriptors, keeping ORB-SLAM's
        thresholds and rotation check (angles of the keyframe's keypoints).
        """
        if self._reference_slot < 0:
            return None
        keyframe = self.map.keyframe(self._reference_slot)
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
        T_cam_world, inliers = self._optimize(self._last.T_cam_world, frame, rows)
        n_inliers = int(np.count_nonzero(inliers))
        if n_inliers < self.config.min_pose_inliers:
            return None
        return OdometryPose(T_cam_world, np.where(inliers, rows, -1), n_inliers, n_inliers)

    # ---- stage 2: local map -------------------------------------------------------------------------
    def _track_local_map(self, frame: Frame, T_cam_world: np.ndarray, rows: np.ndarray):
        """ORB-SLAM2's TrackLocalMap: match local points by projection, optimise; (T, rows, inliers)."""
        window = self.map.local_window(rows)
        if window.reference_slot >= 0:
            self._reference_slot = window.reference_slot
        local_rows = self.map.local_point_rows(window.keyframe_slots)
        matched = rows >= 0
        self.map.increase_visible(rows[matched])
        candidates = local_rows[~np.isin(local_rows, rows[matched])]
        self._search_local_points(frame, T_cam_world, rows, candidates)
        T_cam_world, inliers = self._optimize(T_cam_world, frame, rows)
        self.map.increase_found(rows[inliers])
        rows = np.where(inliers, rows, -1)
        return T_cam_world, rows, int(np.count_nonzero(inliers))

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

    # ---- keyframes ----------------------------------------------------------------------------------
    def _need_keyframe(self, frame: Frame, rows: np.ndarray, n_inliers: int, keyframes_in_flight: int) -> bool:
        if self.config.localization:
            return False  # ORB-SLAM's NeedNewKeyFrame in localisation mode
        n_kfs = self.map.n_keyframes
        if self.config.start_in_map:
            # The map entered (a saved one, or the backend's after a frontend restart) counts: its
            # keyframes were made before ours, which are numbered from past its newest. Counted as
            # the first own keyframe id (culled ones included); ORB-SLAM's rules below ask only
            # whether the map is new (2 keyframes or fewer) or past one second of keyframes.
            n_kfs += self.config.local_map.keyframe_id_start
        paused = self.config.relocalisation.pause_keyframes and self._recently_relocalised(frame)
        if paused and n_kfs > (self.keyframe_config.max_frames or self.camera_fps):
            return False  # ORB-SLAM: no keyframe within a second of a relocalisation
        min_obs = 1 if n_kfs <= 2 else self.config.reference_min_observations
        n_ref = self.map.tracked_points(self._reference_slot, min_obs) if self._reference_slot >= 0 else 0
        tracked_close, untracked_close = close_point_counts(frame.depth_m, rows >= 0, self.th_depth_m)
        inputs = KeyframeDecisionInputs(
            frames_since_last_keyframe=frame.index - self._last_keyframe_index,
            n_keyframes_in_map=n_kfs,
            n_inliers=n_inliers,
            n_reference_tracked=n_ref,
            n_tracked_close=tracked_close,
            n_untracked_close=untracked_close,
            camera_fps=self.camera_fps,
            sensor=self.sensor,
            keyframes_in_flight=keyframes_in_flight,
        )
        return need_new_keyframe(inputs, self.keyframe_config)

    def _make_keyframe(
        self,
        frame: Frame,
        T_cam_world: np.ndarray,
        rows: np.ndarray,
        new_kps: np.ndarray | None = None,
        new_points_world: np.ndarray | None = None,
    ) -> KeyFrame:
        """Make the frame a keyframe with new points at keypoints ``new_kps`` (default: its near
        keypoints with depth; none for a monocular camera), at ``new_points_world`` (default: from
        their depths); updates ``rows`` in place."""
        if new_kps is None and self.calibration.baseline_m is None:
            new_kps = np.zeros(0, dtype=np.int64)  # monocular: local mapping triangulates new points
        elif new_kps is None:
            max_depth_m = self.config.new_points_depth_baselines * self.calibration.baseline_m
            new_kps = select_new_point_keypoints(frame.depth_m, rows >= 0, max_depth_m, self.config.new_points_min)
        T_world_cam = invert_T(T_cam_world)
        feats = frame.features
        new_ids = self.map.new_point_ids(len(new_kps))
        point_ids = np.full(len(rows), -1, dtype=np.int64)
        point_ids[rows >= 0] = self.map.point_ids[rows[rows >= 0]]
        point_ids[new_kps] = new_ids
        keyframe = KeyFrame(
            id=self.map.new_keyframe_id(),
            frame_index=frame.index,
            stamp_ns=frame.stamp_ns,
            T_world_cam=T_world_cam,
            features=feats,
            right_u=frame.right_u,
            depth_m=frame.depth_m,
            map_point_ids=point_ids.astype(np.int64),
            new_point_ids=new_ids,
            new_point_keypoints=new_kps.astype(np.int64),
            new_points_world=(
                unproject_keypoints(feats.px[new_kps], frame.depth_m[new_kps], self.calibration, T_world_cam)
                if new_points_world is None
                else np.asarray(new_points_world, dtype=np.float64).reshape(-1, 3)
            ),
        )
        new_rows = self.map.insert_keyframe(keyframe, point_rows=rows)
        rows[new_kps] = new_rows
        self._reference_slot = self.map.slot_of(keyframe.id)
        self._last_keyframe_index = frame.index
        return keyframe
