"""The frontend's step: images in, a tracked pose (and sometimes a keyframe) out, with stage timings.

``FrontendPipeline.step`` builds the frame (ORB features, stereo matches or RGB-D depths) and
tracks it through the tracker's stages (``tracker``) in ORB-SLAM2's order: start or enter a map,
relocalise a lost frame, the motion model or the reference keyframe, then the local map and the
keyframe decision; localisation mode has its own order (``localisation``).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ConfigError
from zenslam.frontend.config import FrontendConfig
from zenslam.frontend.frame import Frame, make_mono_frame, make_rgbd_frame, make_stereo_frame
from zenslam.frontend.map_sync import MapSync
from zenslam.frontend.orb_extractor import OrbExtractor
from zenslam.frontend.relocalisation import BowTransform
from zenslam.frontend.tracker import CandidateSource, Tracker
from zenslam.frontend.tracking_state import STAGE_TIMING_KEYS, TrackingOutput
from zenslam.frontend.visual_odometry import OdometryPose
from zenslam.geometry import invert_T
from zenslam.schemas.map_update import MapUpdate

__all__ = ["TIMING_KEYS", "FrontendConfig", "FrontendPipeline", "PreparedFrame", "TrackingOutput"]

logger = logging.getLogger(__name__)

TIMING_KEYS = ("extraction", "stereo_matching", *STAGE_TIMING_KEYS, "total")


@dataclass(frozen=True)
class PreparedFrame:
    """A capture turned into a ``Frame`` (ORB features, stereo matches or depths), not yet tracked."""

    frame: Frame
    timings_ms: dict[str, float]  # the frame-building stages of TIMING_KEYS, milliseconds
    elapsed_ms: float  # wall time spent building it, milliseconds
    for_map_start: bool = False  # built with the monocular initialisation's denser extractor


class FrontendPipeline:
    """Builds a frame from the images (ORB, and stereo matches or RGB-D depth) and tracks it.

    With a ``vocabulary``, a lost frame is relocalised against the candidates of the source ``step``
    is given. A monocular camera's frames are extracted with ``monocular.features_factor`` times the
    keypoints while the tracker looks for its two initial frames (ORB-SLAM3 takes 5 times; see
    benchmarks/monocular.md for 8), so that enough finest-level keypoints match between frames far
    enough apart.
    """

    def __init__(
        self, config: FrontendConfig, calibration: PinholeCalibration, sensor: SensorKind, vocabulary: BowTransform | None = None
    ) -> None:
        if sensor not in ("stereo", "rgbd", "mono"):
            raise ConfigError(f"the frontend tracks stereo, rgbd or mono cameras, not sensor {sensor!r}")
        if sensor == "mono" and calibration.baseline_m is not None:
            raise ConfigError(
                f"a mono frontend takes a calibration without baseline, got baseline_m={calibration.baseline_m}: "
                "drop the baseline (the source does when a stereo dataset is played with --sensor mono)"
            )
        if sensor != "mono" and calibration.baseline_m is None:
            raise ConfigError(
                f"a {sensor} frontend needs calibration.baseline_m (stereo baseline or RGB-D virtual baseline)"
            )
        self.config = config
        self.calibration = calibration
        self.sensor = sensor
        self.extractor = OrbExtractor(config.orb)
        self.map_start_extractor = self.extractor
        if sensor == "mono":
            factor = config.tracking.monocular.features_factor
            self.map_start_extractor = OrbExtractor(dataclasses.replace(config.orb, n_features=factor * config.orb.n_features))
        self.tracker = Tracker(calibration, sensor, config.tracking, config.pose, config.keyframe, vocabulary=vocabulary)
        self._first_stamp_ns: int | None = None
        self._rate_known = False

    def prepare(
        self, index: int, stamp_ns: int, left: np.ndarray, right: np.ndarray | None = None, depth_m: np.ndarray | None = None
    ) -> PreparedFrame:
        """Build the frame of one capture without tracking it. It depends on the images alone, not on
        the map, so it may run ahead (while the previous frame waits for the backend) and give the
        same frame as in ``step``."""
        start = time.perf_counter()
        timings = {key: 0.0 for key in TIMING_KEYS}
        for_map_start = self._frames_for_map_start()
        frame = self._make_frame(index, stamp_ns, left, right, depth_m, timings, for_map_start)
        return PreparedFrame(frame, timings, (time.perf_counter() - start) * 1e3, for_map_start)

    def step(
        self,
        index: int,
        stamp_ns: int,
        left: np.ndarray,
        right: np.ndarray | None = None,
        depth_m: np.ndarray | None = None,
        keyframes_in_flight: int = 0,
        prepared: PreparedFrame | None = None,
        candidates: CandidateSource | None = None,
    ) -> TrackingOutput:
        """Track one capture: ``left`` grey uint8 (H, W), with ``right`` (stereo) or ``depth_m`` (RGB-D, metres).

        ``keyframes_in_flight``: keyframes sent to the backend whose map update is not applied yet
        (0 = local mapping idle; always 0 in lockstep, which waits for every update); it throttles the
        keyframe decision. ``prepared``: this capture's frame from ``prepare``, when built ahead; the
        timings' total then adds the time it took to the tracking's. ``candidates``: asks the backend
        for relocalisation candidates (called only while tracking is lost).
        """
        stale = prepared is not None and prepared.for_map_start != self._frames_for_map_start()
        if prepared is None or prepared.frame.index != index or stale:
            prepared = self.prepare(index, stamp_ns, left, right, depth_m)
        start = time.perf_counter()
        self._update_camera_rate(stamp_ns)
        timings = dict(prepared.timings_ms)
        out = self.track(prepared.frame, keyframes_in_flight, candidates)
        timings.update(out.timings_ms)
        timings["total"] = prepared.elapsed_ms + (time.perf_counter() - start) * 1e3
        return dataclasses.replace(out, timings_ms=timings)

    # ---- tracking a built frame through the tracker's stages ------------------------------------
    def track(self, frame: Frame, keyframes_in_flight: int = 0, candidates: CandidateSource | None = None) -> TrackingOutput:
        """Track one built frame: its pose in the world, the inlier count, a keyframe when one is
        made, and the pose relative to the frame's reference keyframe; the timings are the tracking
        stages' (``step`` adds the frame building's). ``keyframes_in_flight`` and ``candidates`` as
        in ``step``."""
        tracker, state = self.tracker, self.tracker.state
        out = self._track(frame, keyframes_in_flight, candidates)
        if out.T_world_cam is not None and tracker.config.start_in_map and candidates is not None:
            tracker.relocalisation.fetch_window(frame, candidates, keyframes_in_flight + (out.keyframe is not None))
            if "map_window" in state.timers.ms:
                out = dataclasses.replace(out, timings_ms={**out.timings_ms, "map_window": state.timers.ms["map_window"]})
        reference = tracker.map.keyframe(state.reference_slot) if state.reference_slot >= 0 else None
        if out.T_world_cam is None or reference is None:
            return out
        return dataclasses.replace(out, reference_keyframe_id=int(reference.id), T_reference_cam=reference.T_cam_world @ out.T_world_cam)

    def _track(self, frame: Frame, keyframes_in_flight: int, candidates: CandidateSource | None) -> TrackingOutput:
        tracker, state, timers = self.tracker, self.tracker.state, self.tracker.state.timers
        outcomes, relocalisation = tracker.outcomes, tracker.relocalisation
        timers.reset()
        if state.last is None and tracker.config.start_in_map:
            return self._enter_map(frame, keyframes_in_flight, candidates)
        if state.last is None:
            return tracker.map_start.start(frame, np.eye(4), "no_depth_points_for_init")
        if tracker.config.localization and state.lost_streak == 0:
            return tracker.localisation.track(frame, candidates)
        relocalising = state.lost_streak > 0 and relocalisation.enabled(candidates)
        failure = None
        if relocalising:
            found, failure = relocalisation.relocalise(frame, candidates)
            if found is not None:
                return outcomes.tracked(frame, found.T_cam_world, found.rows, found.n_inliers, keyframes_in_flight, relocalised=True)
        if tracker.starting_map:
            n_lost = state.lost_streak
            out = tracker.map_start.start(frame, invert_T(state.last.T_cam_world), "no_depth_points_for_reinit")
            if out.state == "ok":
                state.n_reinitialisations += 1
                logger.warning("tracking restarted at frame %d after %d lost frames", frame.index, n_lost)
                return dataclasses.replace(out, state="initializing")
            return out
        if relocalising:
            return outcomes.lost(frame, failure, 0)
        start, pose_ms = time.perf_counter(), timers.pose_ms
        first = self._track_last_frame_or_reference(frame)
        timers.add_less_pose("motion_model_tracking", start, pose_ms)
        if first is None:
            return outcomes.lost(frame, "too_few_matches_motion_model_and_reference", 0)
        start, pose_ms = time.perf_counter(), timers.pose_ms
        local = tracker.local_map_tracking.track(frame, first.T_cam_world, first.rows)
        timers.add_less_pose("local_map_tracking", start, pose_ms)
        min_inliers = relocalisation.min_local_map_inliers(frame)
        if local.n_inliers < min_inliers:
            return outcomes.lost(frame, f"local_map_inliers_below_{min_inliers}", local.n_inliers)
        return outcomes.tracked(frame, local.T_cam_world, local.rows, local.n_inliers, keyframes_in_flight)

    def _track_last_frame_or_reference(self, frame: Frame) -> OdometryPose | None:
        """The pose from the motion model or the reference keyframe, or None."""
        tracker, state = self.tracker, self.tracker.state
        last = state.last
        predicted = state.motion.predict(last.T_cam_world, state.frame_gap(frame))
        if predicted is not None:
            found = tracker.motion_tracking.track(frame, last, predicted)
            if found is not None:
                return found
        found = tracker.reference_tracking.track(frame, state.reference_slot, last.T_cam_world)
        if found is None and predicted is None:
            found = tracker.motion_tracking.track(frame, last, last.T_cam_world)
        return found

    def _enter_map(self, frame: Frame, keyframes_in_flight: int, candidates: CandidateSource | None) -> TrackingOutput:
        """Before the first pose in a saved map: relocalise into it, or stay lost."""
        outcomes, relocalisation = self.tracker.outcomes, self.tracker.relocalisation
        if not relocalisation.enabled(candidates):
            return outcomes.lost(frame, "no_relocalisation_into_the_saved_map", 0)
        found, failure = relocalisation.relocalise(frame, candidates)
        if found is None:
            return outcomes.lost(frame, failure, 0)
        return outcomes.tracked(frame, found.T_cam_world, found.rows, found.n_inliers, keyframes_in_flight, relocalised=True)

    @property
    def may_ask_backend(self) -> bool:
        """Whether the next ``step`` may call its ``candidates`` (``Tracker.may_ask_backend``)."""
        return self.tracker.may_ask_backend

    @property
    def map_sync(self) -> MapSync:
        """What applies the backend's map updates to this pipeline's map cache (the node applies
        them through it directly)."""
        return self.tracker.map_sync

    def apply_map_update(self, update: MapUpdate) -> None:
        """Apply the backend's map correction (replacement semantics) before the next ``step``."""
        self.tracker.map_sync.apply(update)

    def _frames_for_map_start(self) -> bool:
        """The next frame is built with the monocular initialisation's denser extractor."""
        return self.sensor == "mono" and self.tracker.starting_map

    def _make_frame(self, index, stamp_ns, left, right, depth_m, timings: dict[str, float], for_map_start: bool = False) -> Frame:
        if self.sensor == "mono":
            extractor = self.map_start_extractor if for_map_start else self.extractor
            return make_mono_frame(index, stamp_ns, left, self.calibration, extractor, timings)
        if self.sensor == "stereo":
            if right is None:
                raise ConfigError(f"frame {index}: a stereo frontend needs the right image")
            return make_stereo_frame(
                index, stamp_ns, left, right, self.calibration, self.extractor, self.config.stereo, timings
            )
        if depth_m is None:
            raise ConfigError(f"frame {index}: an RGB-D frontend needs the depth image")
        return make_rgbd_frame(index, stamp_ns, left, depth_m, self.calibration, self.extractor, timings)

    def _update_camera_rate(self, stamp_ns: int) -> None:
        """The keyframe decision's max_frames default is the camera rate: take it from the first two stamps."""
        if self._first_stamp_ns is None:
            self._first_stamp_ns = stamp_ns
        elif not self._rate_known and stamp_ns > self._first_stamp_ns:
            self.tracker.camera_fps = 1e9 / (stamp_ns - self._first_stamp_ns)
            self._rate_known = True
