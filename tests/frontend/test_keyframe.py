"""Keyframe helpers: which keypoints get new points, and unprojection."""

from __future__ import annotations

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.frontend.keyframe import select_new_point_keypoints, unproject_keypoints
from zenslam.geometry import invert_T, make_T, so3_exp, transform_points


def test_new_points_cover_close_keypoints_and_at_least_the_nearest_hundred() -> None:
    rng = np.random.default_rng(0)
    depth = rng.uniform(1.0, 60.0, 400).astype(np.float32)
    depth[:20] = -1.0  # no depth
    has_point = np.zeros(400, dtype=bool)
    has_point[20:60] = True
    chosen = select_new_point_keypoints(depth, has_point, th_depth_m=20.0, min_points=100)
    assert not np.any(has_point[chosen]) and np.all(depth[chosen] > 0)
    close_free = np.flatnonzero((depth > 0) & (depth < 20.0) & ~has_point)
    assert set(close_free.tolist()) <= set(chosen.tolist())
    # Few close points: the nearest 101 keypoints with depth (counting those with points) are visited.
    chosen = select_new_point_keypoints(depth, has_point, th_depth_m=2.0, min_points=100)
    order = np.argsort(np.where(depth > 0, depth, np.inf), kind="stable")[:101]
    assert set(chosen.tolist()) == set(order[~has_point[order]].tolist())


def test_unproject_inverts_projection() -> None:
    cal = PinholeCalibration(fx=450.0, fy=460.0, cx=320.0, cy=240.0, width=640, height=480, baseline_m=0.1)
    T_world_cam = make_T(so3_exp(np.array([0.1, -0.2, 0.05])), np.array([1.0, 2.0, -0.5]))
    rng = np.random.default_rng(1)
    p_world = transform_points(T_world_cam, rng.uniform([-2, -1, 2], [2, 1, 8], (50, 3)))
    p_cam = transform_points(invert_T(T_world_cam), p_world)
    px = np.column_stack([cal.fx * p_cam[:, 0] / p_cam[:, 2] + cal.cx, cal.fy * p_cam[:, 1] / p_cam[:, 2] + cal.cy])
    assert np.allclose(unproject_keypoints(px, p_cam[:, 2], cal, T_world_cam), p_world, atol=1e-9)
