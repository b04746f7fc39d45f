"""Frame-to-map tracking for stereo, RGB-D and monocular cameras, ORB-SLAM2's Tracking: the
tracking stages over the state they share; ``FrontendPipeline.track`` runs them in this order.

Per frame: predict the pose with the constant-velocity model and match the last frame's points
by projection (falling back to descriptor matching against the reference keyframe), optimise the
pose, then track the local map (points of the keyframes covisible with the frame) and optimise
again; finally decide whether the frame becomes a keyframe, which creates new points from its
stereo/RGB-D depths (a monocular keyframe makes none: local mapping triangulates them).

A stereo/RGB-D map starts on one frame's depths. A monocular map starts on two frames: the first
frame with enough parallax to a reference frame (``monocular_initialisation``) becomes the
second keyframe, the reference the first, and both are made at that frame's step (the reference
one in ``TrackingOutput.earlier_keyframes``); until then frames report ``initializing`` with a
reason such as ``waiting_for_parallax``.

Lost frames: a lost frame reports ``lost`` with a reason. With a vocabulary and a source of
candidates (the backend's keyframe database, passed to ``FrontendPipeline.step``), every following frame is
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

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.frontend.cache_eviction import CacheEviction
from zenslam.frontend.frame_outcome import FrameOutcomes
from zenslam.frontend.keyframe_decision import KeyframeDecisionConfig, close_depth_threshold_m
from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.local_map_tracking import LocalMapTracking
from zenslam.frontend.localisation import Localisation
from zenslam.frontend.map_pose import MapPoseSolver
from zenslam.frontend.map_start import MapStart
from zenslam.frontend.map_sync import MapSync
from zenslam.frontend.monocular_initialisation import MonocularInitialiser
from zenslam.frontend.motion_model_tracking import MotionModelTracking
from zenslam.frontend.new_keyframes import KeyframeMaker
from zenslam.frontend.reference_keyframe_tracking import ReferenceKeyframeTracking
from zenslam.frontend.relocalisation import BowTransform
from zenslam.frontend.relocalisation_tracking import CandidateSource, RelocalisationTracking
from zenslam.frontend.tracking_config import TrackingConfig
from zenslam.frontend.tracking_state import LastFrame, TrackerState, TrackingState
from zenslam.pose_optimizer import PoseOptimizerConfig

__all__ = ["CandidateSource", "Tracker", "TrackingConfig", "TrackingState"]


class Tracker:
    """The tracking stages of one stereo, RGB-D or monocular camera, the frontend's map cache and
    the state they share (``TrackerState``)."""

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
        self.config = config = config or TrackingConfig()
        pose_config = pose_config or PoseOptimizerConfig()
        keyframe_config = keyframe_config or KeyframeDecisionConfig()
        self.map = LocalMap(config.local_map)
        self.eviction = CacheEviction(self.map)
        self.state = state = TrackerState(camera_fps)
        self.map_sync = MapSync(self.map, state)  # applies the backend's map updates to the cache
        th_depth_m = close_depth_threshold_m(calibration.baseline_m or 0.0, keyframe_config)
        # Localisation mode with a stereo camera weighs the map's points by their covariance and
        # may filter the poses with the odometry's: without the weights a map pose's information is
        # far too confident (an RGB-D camera keeps ORB-SLAM2's exact VO points).
        weighs_points = config.localization and config.localization_point_max_sigma_m is not None and sensor == "stereo"
        filters_poses = weighs_points and config.visual_odometry.fusion == "filter"
        solver = MapPoseSolver(self.map, pose_config, state.timers, weighs_points)
        self.motion_tracking = MotionModelTracking(self.map, config, pose_config, solver, th_depth_m)
        self.reference_tracking = ReferenceKeyframeTracking(self.map, config, solver)
        self.local_map_tracking = LocalMapTracking(self.map, state, config, calibration, sensor, solver)
        self.keyframes = KeyframeMaker(self.map, state, config, keyframe_config, calibration, sensor, th_depth_m)
        self.outcomes = FrameOutcomes(state, self.keyframes, self.eviction, solver, filters_poses)
        monocular = MonocularInitialiser(config.monocular) if sensor == "mono" else None
        self.map_start = MapStart(state, config, self.keyframes, monocular)
        self.relocalisation = RelocalisationTracking(
            self.map, state, config, pose_config, calibration, vocabulary, self.local_map_tracking, self.eviction,
            weighs_points, keyframe_config.max_frames,
        )  # fmt: skip
        self.localisation = Localisation(
            state, config, calibration, pose_config, solver, self.motion_tracking, self.reference_tracking,
            self.local_map_tracking, self.relocalisation, self.outcomes,
        )  # fmt: skip

    camera_fps = property(
        lambda self: self.state.camera_fps,
        lambda self, fps: setattr(self.state, "camera_fps", fps),
        doc="the camera's rate, frames per second (the pipeline sets it from the first stamps)",
    )
    motion = property(lambda self: self.state.motion, doc="the constant-velocity motion model")
    lost_reasons = property(lambda self: self.state.lost_reasons, doc="frames without a pose, counted by reason")
    n_reinitialisations = property(lambda self: self.state.n_reinitialisations, doc="maps started over after a loss")
    n_relocalisations = property(lambda self: self.state.n_relocalisations, doc="relocalisations")
    n_vo_frames = property(lambda self: self.state.odometry.n_frames, doc="localisation mode: frames placed by visual odometry")

    @property
    def last_frame(self) -> LastFrame | None:
        """The last frame tracked (with the map-point row of each keypoint), None before the first."""
        return self.state.last

    @property
    def starting_map(self) -> bool:
        """The next frame may start a map: none exists yet, or tracking was lost long enough to start over."""
        if self.state.last is None:
            return not self.config.start_in_map
        reinit = self.config.reinit_after_lost_frames
        return bool(reinit and self.state.lost_streak >= reinit) and not self.config.localization

    @property
    def may_ask_backend(self) -> bool:
        """Whether tracking the next frame may ask the backend for relocalisation candidates or a
        tracking window: tracking is lost, or the run enters or localises in a saved map."""
        return self.state.lost_streak > 0 or self.config.start_in_map or self.config.localization
