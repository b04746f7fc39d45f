"""What the tracking stages share from frame to frame: the last frame, the reference keyframe, the
loss streak, the motion model, the stage timers, and what one frame's tracking produced."""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from zenslam.frontend.cache_eviction import CacheEviction
from zenslam.frontend.frame import Frame
from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.motion_model import ConstantVelocityModel
from zenslam.frontend.pose_filter import PoseEstimate

TrackingState = Literal["ok", "lost", "initializing"]

# The stages every frame reports, milliseconds (relocalisation and map_window only where they ran).
STAGE_TIMING_KEYS = ("motion_model_tracking", "local_map_tracking", "pose_optimization", "keyframe_decision")


@dataclass(frozen=True)
class TrackingOutput:
    """What the frontend says about one frame.

    ``state`` is "initializing" before a map exists (and on the frame that restarts tracking
    after a long loss), "ok" when the frame was tracked, "lost" otherwise, with ``lost_reason``.
    ``T_world_cam`` (4x4, camera -> world) is None when lost. ``n_tracked`` counts inlier matches
    to map points. ``keyframe`` is the keyframe made at this frame, if any. ``timings_ms`` holds
    milliseconds per stage (keys in ``pipeline.TIMING_KEYS``): the tracking stages exclude the pose
    optimisation, which has its own key; "keyframe_decision" includes making the keyframe. Frames
    that tried to relocalise also have "relocalisation" (the query, matching and local-map tracking).
    """

    index: int
    stamp_ns: int
    state: TrackingState
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


def tracking_output(
    frame: Frame, state: TrackingState, lost_reason: str | None, T_world_cam: np.ndarray | None, n_tracked: int,
    keyframe: KeyFrame | None, timings_ms: dict[str, float], **more,
) -> TrackingOutput:
    """The output of tracking ``frame`` (its index and stamp); ``more``: the optional fields."""
    return TrackingOutput(frame.index, frame.stamp_ns, state, lost_reason, T_world_cam, n_tracked, keyframe, timings_ms, **more)


@dataclass
class LastFrame:
    """A tracked frame with the map row of each keypoint and its pose."""

    frame: Frame
    rows: np.ndarray  # (N,) map point row per keypoint, -1 none
    T_cam_world: np.ndarray
    # (6, 6) of T_cam_world (``pose_filter``) where localisation filters the poses; None: exact
    covariance: np.ndarray | None = None

    def estimate(self) -> PoseEstimate:
        """The frame's pose and covariance (zeros when it has none: taken as exact)."""
        return PoseEstimate(self.T_cam_world, np.zeros((6, 6)) if self.covariance is None else self.covariance)


class StageTimers:
    """Milliseconds per tracking stage of the frame being tracked; the tracking stages are charged
    less the pose optimisation done within them, which has its own key."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = {}

    def reset(self) -> None:
        """A new frame: every stage of ``STAGE_TIMING_KEYS`` at 0."""
        self.ms = dict.fromkeys(STAGE_TIMING_KEYS, 0.0)

    @property
    def pose_ms(self) -> float:
        """Pose optimisation so far in this frame, milliseconds."""
        return self.ms["pose_optimization"]

    def add(self, key: str, start: float) -> None:
        """Charge the time since ``start`` (``time.perf_counter``) to ``key``."""
        self.ms[key] += (time.perf_counter() - start) * 1e3

    def add_less_pose(self, key: str, start: float, pose_ms_at_start: float) -> None:
        """Charge the time since ``start`` to ``key``, less the pose optimisation done meanwhile."""
        pose_ms = self.ms["pose_optimization"] - pose_ms_at_start
        self.ms[key] += (time.perf_counter() - start) * 1e3 - pose_ms

    def snapshot(self) -> dict[str, float]:
        return dict(self.ms)


@dataclass
class OdometryState:
    """Localisation mode's visual odometry between map-tracked frames."""

    on_vo: bool = False  # the last frame was placed by visual odometry
    # The frame whose VO points frames on visual odometry are matched to, the VO matches of the
    # first frame matched to it (0 before that), and whether the odometry of the frame being
    # tracked came from it.
    anchor: LastFrame | None = None
    anchor_matches: int = 0
    from_anchor: bool = False
    n_frames: int = 0  # frames placed by visual odometry
    path_m: float = 0.0  # the camera's path on visual odometry since the map was last tracked

    def map_tracked(self) -> None:
        """A frame was tracked in the map: visual odometry ends."""
        self.on_vo = False
        self.anchor = None
        self.path_m = 0.0


@dataclass
class TrackerState:
    """The tracking state carried from frame to frame, shared by the tracking stages."""

    camera_fps: float  # the camera's rate: the keyframe decision's and relocalisation's one second of frames
    motion: ConstantVelocityModel = field(default_factory=ConstantVelocityModel)
    last: LastFrame | None = None  # the last successfully tracked frame
    reference_slot: int = -1  # ORB-SLAM's reference keyframe, a slot of the map cache
    last_keyframe_index: int = -1  # frame index of the newest keyframe
    lost_streak: int = 0  # consecutive frames without a pose
    relocalised_at: int = -(1 << 62)  # frame index of the last relocalisation
    lost_reasons: Counter[str] = field(default_factory=Counter)
    n_reinitialisations: int = 0
    n_relocalisations: int = 0
    timers: StageTimers = field(default_factory=StageTimers)
    odometry: OdometryState = field(default_factory=OdometryState)

    def frame_gap(self, frame: Frame) -> int:
        """Frames from the last tracked frame to ``frame`` (1 unless live mode skipped frames), by index
        or, when a source numbers only the frames it passes on, by stamp."""
        return self.motion.frames_between(frame.index - self.last.frame.index, self.elapsed_ns(frame))

    def elapsed_ns(self, frame: Frame) -> int:
        """Time from the last tracked frame to ``frame``."""
        return frame.stamp_ns - self.last.frame.stamp_ns

    def recently_relocalised(self, frame: Frame, max_frames: float) -> bool:
        """Within ORB-SLAM's mMaxFrames (``max_frames``, 0: one second of frames) after a relocalisation."""
        window = max_frames or self.camera_fps
        return frame.index < self.relocalised_at + window

    def evict(self, eviction: CacheEviction, unanswered: int, force: bool = False) -> None:
        """Evict the map cache when due (or ``force``), around the last frame's window; ``unanswered``
        newest keyframes (the backend's updates of them not applied yet) stay. Remaps the slots and
        rows held here."""
        last = self.last
        done = eviction.maybe_evict(last.rows, self.reference_slot, unanswered, keep_rows=last.rows, force=force)
        if done is None:
            return
        last.rows = np.where(last.rows >= 0, done.row_map[last.rows], -1)
        self.reference_slot = int(done.slot_map[self.reference_slot]) if self.reference_slot >= 0 else -1
