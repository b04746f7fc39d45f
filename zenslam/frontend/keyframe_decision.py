"""When to make a keyframe: ORB-SLAM2's ``Tracking::NeedNewKeyFrame`` criteria as a pure function."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.camera import SensorKind


@dataclass(frozen=True)
class KeyframeDecisionConfig:
    """Thresholds of the keyframe decision (ORB-SLAM2 defaults)."""

    min_frames: int = 0  # frames; no keyframe sooner than this after the last one when mapping is busy
    max_frames: int = 0  # frames; a keyframe is due after this many; 0 = the camera rate (frames/s)
    ref_ratio_stereo: float = 0.75  # inliers / reference keyframe's tracked points below this -> keyframe
    ref_ratio_mono: float = 0.9  # the same for monocular tracking
    ref_ratio_first_keyframes: float = 0.4  # the same while the map has fewer than 2 keyframes
    weak_tracking_ratio: float = 0.25  # inliers below this fraction of the reference's points = weak
    close_depth_baselines: float = 35.0  # close points are nearer than this many baselines (th_depth)
    tracked_close_max: int = 100  # fewer tracked close points than this ...
    untracked_close_min: int = 70  # ... and more untracked close points than this -> insert
    min_inliers: int = 15  # never make a keyframe from fewer inlier matches than this (exclusive)
    # keyframes; while local mapping is busy, stereo/RGB-D still insert a due keyframe only while
    # fewer than this many wait in its queue; mono never does. ORB-SLAM's 3: where mapping falls
    # behind tracking, fewer held back keyframes leave tracking on fewer and older points, which
    # costs more (lost frames, less accurate runs) than the local BAs deferred for the queued
    # ones (benchmarks/frames_from_bus.md).
    max_queued_keyframes: int = 3


@dataclass(frozen=True)
class KeyframeDecisionInputs:
    """What the tracker knows about the current frame when deciding."""

    frames_since_last_keyframe: int  # frames since the last keyframe (1 = the next frame)
    n_keyframes_in_map: int  # keyframes in the map
    n_inliers: int  # inlier matches to map points after local-map tracking
    n_reference_tracked: int  # the reference keyframe's points with enough observations
    n_tracked_close: int  # close keypoints (depth < th_depth) matched to a map point
    n_untracked_close: int  # close keypoints with depth but no map point
    camera_fps: float  # frames per second of the camera (for max_frames = 0)
    sensor: SensorKind = "stereo"
    # keyframes sent to the backend whose map update has not been applied yet (0 in lockstep, where
    # the frontend waits for each update): local mapping is idle when none is in flight
    keyframes_in_flight: int = 0

    @property
    def local_mapping_idle(self) -> bool:
        """No keyframe is waiting for, or in, local mapping."""
        return self.keyframes_in_flight == 0

    @property
    def keyframes_queued(self) -> int:
        """Keyframes waiting in local mapping's queue: those in flight but the one being mapped."""
        return max(self.keyframes_in_flight - 1, 0)


def close_point_counts(depth_m: np.ndarray, tracked: np.ndarray, th_depth_m: float) -> tuple[int, int]:
    """(tracked, untracked) counts of keypoints with 0 < depth < th_depth_m metres."""
    depth_m = np.asarray(depth_m)
    close = (depth_m > 0) & (depth_m < th_depth_m)
    n_tracked = int(np.count_nonzero(close & np.asarray(tracked, dtype=bool)))
    return n_tracked, int(np.count_nonzero(close)) - n_tracked


def close_depth_threshold_m(baseline_m: float, config: KeyframeDecisionConfig) -> float:
    """ORB-SLAM's th_depth in metres: ``close_depth_baselines`` stereo (or virtual) baselines."""
    return config.close_depth_baselines * baseline_m


def need_new_keyframe(inputs: KeyframeDecisionInputs, config: KeyframeDecisionConfig) -> bool:
    """ORB-SLAM2's decision: (c1a or c1b or c1c) and c2.

    c1a: ``max_frames`` have passed; c1b: ``min_frames`` have passed and local mapping is idle;
    c1c (not mono): tracking is weak (inliers < 0.25 x reference) or close points are needed;
    c2: (inliers < ratio x reference, or close points are needed) and inliers > ``min_inliers``.
    Close points are needed when fewer than 100 close points are tracked and more than 70 could
    be created. When both hold and local mapping is busy, stereo/RGB-D insert only while fewer
    than ``max_queued_keyframes`` keyframes are queued, mono never (ORB-SLAM2 also interrupts local
    BA there; here the backend defers its BA on its own when keyframes are queued). ORB-SLAM's
    relocalisation guard is absent: this frontend does not relocalise.
    """
    mono = inputs.sensor == "mono"
    max_frames = config.max_frames if config.max_frames > 0 else max(int(round(inputs.camera_fps)), 1)
    need_close = (
        not mono
        and inputs.n_tracked_close < config.tracked_close_max
        and inputs.n_untracked_close > config.untracked_close_min
    )
    if mono:
        ratio = config.ref_ratio_mono
    elif inputs.n_keyframes_in_map < 2:
        ratio = config.ref_ratio_first_keyframes
    else:
        ratio = config.ref_ratio_stereo
    c1a = inputs.frames_since_last_keyframe >= max_frames
    c1b = inputs.frames_since_last_keyframe >= config.min_frames and inputs.local_mapping_idle
    c1c = not mono and (inputs.n_inliers < inputs.n_reference_tracked * config.weak_tracking_ratio or need_close)
    c2 = (inputs.n_inliers < inputs.n_reference_tracked * ratio or need_close) and inputs.n_inliers > config.min_inliers
    if not ((c1a or c1b or c1c) and c2):
        return False
    if inputs.local_mapping_idle:
        return True
    return not mono and inputs.keyframes_queued < config.max_queued_keyframes
