"""ORB-SLAM2's keyframe decision: each criterion, flipped alone, flips the decision."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from zenslam.frontend.keyframe_decision import (
    KeyframeDecisionConfig,
    KeyframeDecisionInputs,
    close_depth_threshold_m,
    close_point_counts,
    need_new_keyframe,
)

CONFIG = KeyframeDecisionConfig()

# A well-tracked frame: many inliers relative to the reference keyframe, close points tracked.
STEADY = KeyframeDecisionInputs(
    frames_since_last_keyframe=3,
    n_keyframes_in_map=5,
    n_inliers=400,
    n_reference_tracked=450,
    n_tracked_close=300,
    n_untracked_close=200,
    camera_fps=10.0,
    sensor="stereo",
)


def decide(**changes) -> bool:
    return need_new_keyframe(dataclasses.replace(STEADY, **changes), CONFIG)


def test_steady_tracking_needs_no_keyframe() -> None:
    assert not decide()


def test_few_inliers_relative_to_reference_makes_a_keyframe() -> None:
    # 0.75 x 450 = 337.5: just above keeps, just below inserts.
    assert not decide(n_inliers=338)
    assert decide(n_inliers=337)


def test_reference_ratio_depends_on_sensor_and_map_size() -> None:
    # Mono uses 0.9: 400 < 0.9 x 450 = 405.
    assert decide(sensor="mono")
    # With fewer than 2 keyframes the ratio is 0.4: 170 < 180 inserts, 190 does not.
    assert decide(n_keyframes_in_map=1, n_inliers=170)
    assert not decide(n_keyframes_in_map=1, n_inliers=190)
    assert decide(n_keyframes_in_map=2, n_inliers=190)


def test_close_points_needed_makes_a_keyframe() -> None:
    assert decide(n_tracked_close=99, n_untracked_close=71)
    assert not decide(n_tracked_close=100, n_untracked_close=71)
    assert not decide(n_tracked_close=99, n_untracked_close=70)
    # Mono never needs close points.
    assert not decide(sensor="mono", n_tracked_close=0, n_untracked_close=500, n_inliers=420)


def test_too_few_inliers_never_makes_a_keyframe() -> None:
    assert decide(n_inliers=16, n_tracked_close=0)
    assert not decide(n_inliers=15, n_tracked_close=0)


def test_frame_count_conditions_when_mapping_is_busy() -> None:
    busy = dict(keyframes_in_flight=1, n_inliers=330)  # c2 holds (330 < 337.5), c1c does not
    assert not decide(**busy, frames_since_last_keyframe=9)
    assert decide(**busy, frames_since_last_keyframe=10)  # max_frames = fps = 10
    config = KeyframeDecisionConfig(max_frames=4)
    assert need_new_keyframe(dataclasses.replace(STEADY, **busy, frames_since_last_keyframe=4), config)
    # Weak tracking (c1c) inserts even when busy and early.
    assert decide(keyframes_in_flight=1, frames_since_last_keyframe=1, n_inliers=100)
    # min_frames with an idle mapper (c1b).
    config = KeyframeDecisionConfig(min_frames=3)
    assert not need_new_keyframe(dataclasses.replace(STEADY, n_inliers=330, frames_since_last_keyframe=2), config)
    assert need_new_keyframe(dataclasses.replace(STEADY, n_inliers=330, frames_since_last_keyframe=3), config)


def test_close_point_counts() -> None:
    depth = np.array([-1.0, 0.5, 2.0, 10.0, 30.0, 0.0], dtype=np.float32)
    tracked = np.array([True, True, False, True, True, False])
    th = close_depth_threshold_m(0.5, CONFIG)
    assert th == pytest.approx(17.5)
    assert close_point_counts(depth, tracked, th) == (2, 1)


def test_busy_mapping_throttles_keyframes_by_queue_length() -> None:
    """ORB-SLAM's rule, zenslam's default: busy local mapping takes a due stereo/RGB-D keyframe only
    while < 3 are queued; a smaller queue throttles sooner."""
    due = dict(frames_since_last_keyframe=1, n_inliers=100)  # weak tracking: c1c and c2 hold
    assert KeyframeDecisionConfig().max_queued_keyframes == 3

    def decide(**changes) -> bool:
        return need_new_keyframe(dataclasses.replace(STEADY, **changes), KeyframeDecisionConfig())

    assert decide(**due, keyframes_in_flight=0)  # idle
    # In flight = queued + the one being mapped: 1..3 in flight leave 0..2 queued.
    for in_flight in (1, 2, 3):
        assert decide(**due, keyframes_in_flight=in_flight), in_flight
    assert not decide(**due, keyframes_in_flight=4)  # 3 queued
    assert not decide(**due, keyframes_in_flight=9)
    assert decide(**due, sensor="rgbd", keyframes_in_flight=3)
    config = dataclasses.replace(KeyframeDecisionConfig(), max_queued_keyframes=1)
    assert need_new_keyframe(dataclasses.replace(STEADY, **due, keyframes_in_flight=1), config)
    assert not need_new_keyframe(dataclasses.replace(STEADY, **due, keyframes_in_flight=2), config)


def test_busy_mapping_never_takes_a_mono_keyframe() -> None:
    due = dict(sensor="mono", frames_since_last_keyframe=10, n_inliers=100)  # c1a and c2 hold
    assert decide(**due, keyframes_in_flight=0)
    assert not decide(**due, keyframes_in_flight=1)
