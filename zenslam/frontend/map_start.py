"""Starting a map: a stereo/RGB-D map on one frame's depths, a monocular one on two frames with
enough parallax (``monocular_initialisation``)."""

from __future__ import annotations

import logging
import time

import numpy as np

from zenslam.frontend.frame import Frame
from zenslam.frontend.monocular_initialisation import InitialMap, MonocularInitialiser
from zenslam.frontend.new_keyframes import KeyframeMaker
from zenslam.frontend.tracking_config import TrackingConfig
from zenslam.frontend.tracking_state import LastFrame, TrackerState, TrackingOutput, tracking_output
from zenslam.geometry import invert_T, transform_points

logger = logging.getLogger(__name__)


class MapStart:
    """Starts maps; ``monocular`` (None for a stereo/RGB-D camera) looks for the two initial frames."""

    def __init__(self, state: TrackerState, config: TrackingConfig, keyframes: KeyframeMaker, monocular: MonocularInitialiser | None) -> None:
        self.state = state
        self.config = config
        self.keyframes = keyframes
        self.monocular = monocular

    def start(self, frame: Frame, T_world_cam: np.ndarray, reason: str) -> TrackingOutput:
        """A new map at ``T_world_cam``: from this frame's depths, or for a monocular camera from two
        frames; ``reason`` is the stereo/RGB-D frame's when it has too few keypoints or depths."""
        if self.monocular is None:
            return self._initialise(frame, T_world_cam, reason)
        found = self.monocular.try_frame(frame)
        if isinstance(found, str):
            self.state.lost_reasons[found] += 1
            self.state.lost_streak += 1
            return tracking_output(frame, "initializing", found, None, 0, None, self.state.timers.snapshot())
        return self._initialise_monocular(frame, found, T_world_cam)

    def _initialise_monocular(self, frame: Frame, found: InitialMap, T_world_ref: np.ndarray) -> TrackingOutput:
        """The two keyframes of a monocular map found at ``frame``: the reference at ``T_world_ref``
        with the triangulated points, then the current frame observing them."""
        state = self.state
        start = time.perf_counter()
        reference, current = found.reference, found.current
        ref_rows = np.full(reference.n_keypoints, -1, dtype=np.int64)
        first = self.keyframes.make(
            reference, invert_T(T_world_ref), ref_rows, found.reference_keypoints, transform_points(T_world_ref, found.p_ref)
        )
        T_cam_world = found.T_cur_ref @ invert_T(T_world_ref)
        rows = np.full(current.n_keypoints, -1, dtype=np.int64)
        rows[found.current_keypoints] = ref_rows[found.reference_keypoints]
        second = self.keyframes.make(current, T_cam_world, rows, np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
        state.timers.add("keyframe_decision", start)
        state.motion.reset()
        state.last = LastFrame(current, rows, T_cam_world)
        state.lost_streak = 0
        n_points = len(found.reference_keypoints)
        logger.info(
            "monocular map initialised at frames %d and %d (%s, parallax %.1f deg) with %d points",
            reference.index, current.index, found.model, found.parallax_deg, n_points,
        )  # fmt: skip
        return tracking_output(
            frame, "ok", None, invert_T(T_cam_world), n_points, second, state.timers.snapshot(), earlier_keyframes=(first,)
        )

    def _initialise(self, frame: Frame, T_world_cam: np.ndarray, reason: str) -> TrackingOutput:
        """A new map from one frame's depths at ``T_world_cam``: one keyframe, a point per depth."""
        state = self.state
        n_depth = int(np.count_nonzero(frame.depth_m > 0))
        if len(frame.features) <= self.config.min_init_keypoints or n_depth < self.config.min_init_depth_points:
            state.lost_reasons[reason] += 1
            state.lost_streak += 1
            return tracking_output(frame, "initializing", reason, None, 0, None, state.timers.snapshot())
        start = time.perf_counter()
        rows = np.full(len(frame.features), -1, dtype=np.int64)
        new_kps = np.flatnonzero(frame.depth_m > 0)
        T_cam_world = invert_T(T_world_cam)
        keyframe = self.keyframes.make(frame, T_cam_world, rows, new_kps)
        state.timers.add("keyframe_decision", start)
        state.motion.reset()
        state.last = LastFrame(frame, rows, T_cam_world)
        state.lost_streak = 0
        logger.info("map initialised at frame %d with %d points", frame.index, len(new_kps))
        T_world_cam = np.asarray(T_world_cam, dtype=float).copy()
        return tracking_output(frame, "ok", None, T_world_cam, len(new_kps), keyframe, state.timers.snapshot())
