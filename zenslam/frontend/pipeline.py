"""The frontend's step: images in, a tracked pose (and sometimes a keyframe) out, with stage timings."""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ConfigError
from zenslam.frontend.config import FrontendConfig
from zenslam.frontend.frame import Frame, make_mono_frame, make_rgbd_frame, make_stereo_frame
from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.orb_extractor import OrbExtractor
from zenslam.frontend.relocalisation import BowTransform
from zenslam.frontend.tracker import CandidateSource, Tracker
from zenslam.schemas.map_update import MapUpdate

logger = logging.getLogger(__name__)

TIMING_KEYS = (
    "extraction",
    "stereo_matching",
    "motion_model_tracking",
    "local_map_tracking",
    "pose_optimization",
    "keyframe_decision",
    "total",
)


@dataclass(frozen=True)
class TrackingOutput:
    """What the frontend says about one frame.

    ``state`` is "initializing" before a map exists (and on the frame that restarts tracking
    after a long loss), "ok" when the frame was tracked, "lost" otherwise, with ``lost_reason``.
    ``T_world_cam`` (4x4, camera -> world) is None when lost. ``n_tracked`` counts inlier matches
    to map points. ``keyframe`` is the keyframe made at this frame, if any. ``timings_ms`` holds
    milliseconds per stage (keys in ``TIMING_KEYS``): the tracking stages exclude the pose
    optimisation, which has its own key; "keyframe_decision" includes making the keyframe. Frames
    that tried to relocalise also have "relocalisation" (the query, matching and local-map tracking).
    """

    index: int
    stamp_ns: int
    state: Literal["ok", "lost", "initializing"]
    lost_reason: str | None
    T_world_cam: np.ndarray | None
    n_tracked: int
    keyframe: KeyFrame | None
    timings_ms: dict[str, float]
    reference_keyframe_id: int = -1  # the keyframe the pose is kept relative to, -1 none
    T_reference_cam: np.ndarray | None = None  # (4, 4) the camera in that keyframe's frame
    relocalised: bool = False  # tracking was lost (or, localising, on visual odometry) before this frame and found the map again here
    earlier_keyframes: tuple[KeyFrame, ...] = ()  # made at this step from earlier frames, sent before ``keyframe``

    @property
    def keyframes_made(self) -> tuple[KeyFrame, ...]:
        """Every keyframe made at this step, in the order the backend takes them."""
        return (*self.earlier_keyframes, *((self.keyframe,) if self.keyframe is not None else ()))


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
    benchmarks/README.md for 8), so that enough finest-level keypoints match between frames far
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
        result = self.tracker.track(prepared.frame, keyframes_in_flight, candidates)
        timings.update(result.timings_ms)
        timings["total"] = prepared.elapsed_ms + (time.perf_counter() - start) * 1e3
        return TrackingOutput(
            index=index,
            stamp_ns=stamp_ns,
            state=result.state,
            lost_reason=result.lost_reason,
            T_world_cam=result.T_world_cam,
            n_tracked=result.n_tracked,
            keyframe=result.keyframe,
            timings_ms=timings,
            reference_keyframe_id=result.reference_keyframe_id,
            T_reference_cam=result.T_reference_cam,
            relocalised=result.relocalised,
            earlier_keyframes=result.earlier_keyframes,
        )

    @property
    def may_ask_backend(self) -> bool:
        """Whether the next ``step`` may call its ``candidates`` (``Tracker.may_ask_backend``)."""
        return self.tracker.may_ask_backend

    def apply_map_update(self, update: MapUpdate) -> None:
        """Apply the backend's map correction (replacement semantics) before the next ``step``."""
        self.tracker.apply_map_update(update)

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
