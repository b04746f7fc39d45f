"""What a frame's tracking leaves behind: a tracked frame goes through the keyframe decision and
becomes the last frame the motion model and the next frame's matching start from; a lost frame
counts its reason and stops the motion model."""

from __future__ import annotations

import logging
import time

import numpy as np

from zenslam.frontend.cache_eviction import CacheEviction
from zenslam.frontend.frame import Frame
from zenslam.frontend.map_pose import MapPoseSolver
from zenslam.frontend.new_keyframes import KeyframeMaker
from zenslam.frontend.pose_filter import PoseEstimate
from zenslam.frontend.tracking_state import LastFrame, TrackerState, TrackingOutput, tracking_output
from zenslam.geometry import invert_T

logger = logging.getLogger(__name__)


class FrameOutcomes:
    """Records tracked and lost frames in ``state``. ``filters_poses``: a tracked frame's pose gets
    its covariance (``pose_filter``), from its map inliers unless given."""

    def __init__(
        self, state: TrackerState, keyframes: KeyframeMaker, eviction: CacheEviction, solver: MapPoseSolver, filters_poses: bool
    ) -> None:
        self.state = state
        self.keyframes = keyframes
        self.eviction = eviction
        self.solver = solver
        self.filters_poses = filters_poses

    def tracked(
        self, frame: Frame, T_cam_world: np.ndarray, rows: np.ndarray, n_inliers: int, keyframes_in_flight: int,
        relocalised: bool = False, covariance: np.ndarray | None = None,
    ) -> TrackingOutput:
        """A frame tracked in the local map: the keyframe decision, the motion model (restarted after
        a relocalisation, as ORB-SLAM's has no velocity across a lost frame) and the last frame,
        with the pose's ``covariance`` where localisation filters the poses (None: the map
        inliers' alone)."""
        state = self.state
        start = time.perf_counter()
        keyframe = None
        if self.keyframes.needed(frame, rows, n_inliers, keyframes_in_flight):
            keyframe = self.keyframes.make(frame, T_cam_world, rows)
        state.timers.add("keyframe_decision", start)
        if relocalised:
            state.motion.reset()
        else:
            state.motion.update(state.last.T_cam_world, T_cam_world, state.frame_gap(frame), state.elapsed_ns(frame))
        if covariance is None and self.filters_poses:
            covariance = PoseEstimate.from_information(T_cam_world, self.solver.information(frame, T_cam_world, rows)).covariance
        state.last = LastFrame(frame, rows, T_cam_world, covariance)
        state.lost_streak = 0
        state.odometry.map_tracked()
        if keyframe is not None:
            state.evict(self.eviction, keyframes_in_flight + 1)
        return tracking_output(
            frame, "ok", None, invert_T(T_cam_world), n_inliers, keyframe, state.timers.snapshot(), relocalised=relocalised
        )

    def lost(self, frame: Frame, reason: str, n_tracked: int) -> TrackingOutput:
        """A frame without a pose, for ``reason``, with ``n_tracked`` matches."""
        state = self.state
        state.lost_reasons[reason] += 1
        state.lost_streak += 1
        state.motion.reset()
        logger.debug("frame %d lost: %s", frame.index, reason)
        return tracking_output(frame, "lost", reason, None, n_tracked, None, state.timers.snapshot())
