"""Loop correction: the loop's points fused into the drifted neighbourhood, or the map left as it was."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from zenslam.backend.loop_closing import LoopCloser, LoopOutcome
from zenslam.backend.loop_closing_config import LoopClosingConfig
from zenslam.backend.loop_detection import Detection
from zenslam.backend.loop_messages import loop_messages
from zenslam.backend.loop_verification import LoopMatch, Rejection
from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.camera import PinholeCalibration
from zenslam.errors import ConfigError
from zenslam.geometry import invert_T, make_T, so3_exp, transform_points
from zenslam.schemas import codec

from test_map import map_state  # noqa: E402  (tests/backend is on the path under pytest)

CAL = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)
N = 60
DRIFT = np.array([0.01, 0.0, 0.005])  # metres: where the current side's map is off the loop side's


def view(kf_id: int, T_world_cam: np.ndarray, p_true: np.ndarray, d: np.ndarray) -> BackendKeyframe:
    """A stereo keyframe whose keypoint i is the exact projection of true point i (the pose as given)."""
    p_cam = transform_points(invert_T(T_world_cam), p_true)
    px = CAL.fx * p_cam[:, :2] / p_cam[:, 2:] + [CAL.cx, CAL.cy]
    return BackendKeyframe(
        id=kf_id, stamp_ns=kf_id, T_world_cam=T_world_cam, calibration=CAL, sensor="stereo", keypoints_px=px,
        levels=np.zeros(N, np.int64), angles_deg=np.zeros(N), right_u=px[:, 0] - CAL.bf / p_cam[:, 2],
        depth_m=p_cam[:, 2].copy(), descriptors=d.copy(), scale_factors=1.2 ** np.arange(8),
        map_point_ids=np.full(N, -1, np.int64),
    )  # fmt: skip


def revisit() -> tuple[BackendMap, LoopMatch]:
    """Keyframes 0-3 (x = 0 .. 0.3 m) map points 0-59; keyframes 4 and 5 come back to x = 0 and
    0.1 m with a drifted map of the same scene (points 200-259, poses and points off by DRIFT).
    The match: keyframe 4's keypoints 0-29 matched to loop points 0-29, its true pose the correction."""
    rng = np.random.default_rng(7)
    p = np.column_stack([rng.uniform(-2, 2, N), rng.uniform(-1.5, 1.5, N), rng.uniform(4, 8, N)])
    d = rng.integers(0, 256, (N, 32), dtype=np.uint8)
    bmap = BackendMap()
    for i in range(N):
        bmap.add_point(i, p[i], 0)
    for k in range(4):
        kf = view(k, make_T(np.eye(3), [0.1 * k, 0.0, 0.0]), p, d)
        kf.map_point_ids[:] = np.arange(N)
        bmap.add_keyframe(kf)
    for i in range(N):
        bmap.add_point(200 + i, p[i] + DRIFT, 4)
    for k, x in ((4, 0.0), (5, 0.1)):
        T_true = make_T(np.eye(3), [x, 0.0, 0.0])
        kf = view(k, T_true, p, d)
        kf.T_world_cam = make_T(np.eye(3), T_true[:3, 3] + DRIFT)
        kf.map_point_ids[:] = 200 + np.arange(N)
        bmap.add_keyframe(kf)
    bmap.take_changes()
    match = LoopMatch(
        keyframe_id=4, loop_keyframe_id=0, T_cur_loop=make_T(np.eye(3), [0.0, 0.0, 0.0]), scale=1.0,
        T_world_cur_corrected=make_T(np.eye(3), [0.0, 0.0, 0.0]), inliers=30, loop_point_ids=np.arange(N),
        matched_keypoints=np.arange(30), matched_point_ids=np.arange(30),
    )  # fmt: skip
    return bmap, match


class _RejectedAfterFusion(LoopCloser):
    """A pose graph that accepts the check before fusion and rejects the loop after it."""

    def _optimize(self, poses_before, corrected, loop_edges, match, with_scale):
        result = super()._optimize(poses_before, corrected, loop_edges, match, with_scale)
        self.calls = getattr(self, "calls", 0) + 1
        return dataclasses.replace(result, stats={**result.stats, "loop_rejected": self.calls > 1})


def test_a_loop_fuses_the_drifted_duplicates_and_moves_the_neighbourhood() -> None:
    bmap, match = revisit()
    fused, connections, stats = LoopCloser(bmap, None, LoopClosingConfig()).correct(match, with_scale=False)
    assert not stats.get("loop_rejected")
    assert fused >= N and connections > 0
    assert not any(200 + i in bmap.points for i in range(N))  # every duplicate merged into the loop's point
    assert set(bmap.points[0].observations) == {0, 1, 2, 3, 4, 5}
    for k, x in ((4, 0.0), (5, 0.1)):
        np.testing.assert_allclose(bmap.keyframe(k).T_world_cam[:3, 3], [x, 0.0, 0.0], atol=1e-6)
    assert bmap.check_consistency() == []


def test_a_loop_rejected_after_fusion_leaves_the_map_as_it_was() -> None:
    bmap, match = revisit()
    before = map_state(bmap)
    fused, connections, stats = _RejectedAfterFusion(bmap, None, LoopClosingConfig()).correct(match, with_scale=False)
    assert stats["loop_rejected"] and (fused, connections) == (0, 0)
    assert map_state(bmap) == before
    assert bmap.check_consistency() == []


def test_a_loop_moving_the_keyframe_beyond_the_drift_budget_is_refused() -> None:
    """The revisit moves keyframe 4 by |DRIFT| = 1.1 cm over the keyframes' 0.59 m path (1.9%)."""
    bmap, match = revisit()
    moved, path = np.linalg.norm(DRIFT), 0.3 + np.linalg.norm(DRIFT - [0.3, 0.0, 0.0])
    assert LoopCloser(bmap, None, LoopClosingConfig()).drift_budget_exceeded(match) is None  # 5%
    assert LoopCloser(bmap, None, LoopClosingConfig(drift_budget=None)).drift_budget_exceeded(match) is None  # no limit
    tight = LoopClosingConfig(drift_budget=0.01)
    why = LoopCloser(bmap, None, tight).drift_budget_exceeded(match)
    assert why is not None and f"{moved:.3f} m" in why and f"{path:.2f} m path" in why and "budget 1%" in why
    assert LoopCloser(bmap, None, tight).drift_budget_exceeded(match, with_scale=True) is None  # monocular: its own 10%
    assert LoopCloser(bmap, None, dataclasses.replace(tight, drift_budget_monocular=None)).drift_budget_exceeded(match, True) is None
    assert LoopCloser(bmap, None, dataclasses.replace(tight, drift_budget_monocular=0.01)).drift_budget_exceeded(match, True) is not None
    with pytest.raises(ConfigError, match="drift_budget_monocular=0"):
        LoopClosingConfig(drift_budget_monocular=0.0)


def test_a_loop_refused_after_verification_publishes_the_transform_it_asked_for() -> None:
    bmap, match = revisit()
    before = bmap.keyframe(4).T_world_cam.copy()
    refused = Rejection(match.loop_keyframe_id, "drift budget: ...", match)
    failed = Rejection(2, "12 BoW matches < 20")
    detection = Detection(keyframe_id=4, min_score=0.1, candidates=(), consistent=(match.loop_keyframe_id, 2))
    messages = loop_messages(bmap, LoopOutcome(detection, (refused, failed)), before)
    outcomes = [(m.loop_keyframe_id, m.accepted, m.inliers) for m in messages]
    assert outcomes == [(match.loop_keyframe_id, False, match.inliers), (2, False, 0)]
    np.testing.assert_allclose(messages[0].T_cur_loop, match.T_cur_loop)
    np.testing.assert_allclose(messages[1].T_cur_loop, np.eye(4))


def test_a_monocular_loop_message_carries_a_rotation_and_the_scale_apart() -> None:
    """p_cur = s R p_loop + t: the message's T_cur_loop holds R and t (a rigid transform), ``scale`` s."""
    bmap, match = revisit()
    R = so3_exp(np.array([0.0, 0.2, 0.05]))
    sim3 = dataclasses.replace(match, T_cur_loop=make_T(R, [0.1, 0.0, 0.3]), scale=1.4)
    detection = Detection(keyframe_id=4, min_score=0.1, candidates=(), consistent=(match.loop_keyframe_id,))
    refused = Rejection(match.loop_keyframe_id, "drift budget: ...", sim3)
    (message,) = loop_messages(bmap, LoopOutcome(detection, (refused,)), bmap.keyframe(4).T_world_cam)
    np.testing.assert_allclose(message.T_cur_loop[:3, :3], R, atol=1e-12)
    assert message.scale == 1.4
    back = codec.decode_loop(codec.encode_loop(message))
    np.testing.assert_allclose(back.T_cur_loop, sim3.T_cur_loop, atol=1e-9)
