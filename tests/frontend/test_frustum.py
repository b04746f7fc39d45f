"""ORB-SLAM's isInFrustum over arrays: every visibility test rejects its own case."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.frontend.frustum import project_in_frustum
from zenslam.map_point_rules import predict_scale_level


def test_project_in_frustum_applies_each_visibility_test() -> None:
    cal = PinholeCalibration(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480, baseline_m=0.1)
    p_world = np.array(
        [
            [0.0, 0.0, 5.0],  # visible
            [0.0, 0.0, -5.0],  # behind
            [10.0, 0.0, 5.0],  # outside the image
            [0.0, 0.0, 50.0],  # beyond 1.2 x max distance
            [0.0, 0.0, 5.0],  # viewed from the side of its normal (cos < 0.5)
        ]
    )
    normals = np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 0, 1.0], [0, 0, 1.0], [1.0, 0, 0.2]])
    min_d = np.full(5, 1.0)
    max_d = np.array([10.0, 10.0, 10.0, 10.0, 10.0])
    proj = project_in_frustum(np.eye(4), p_world, normals, min_d, max_d, cal, 1.2, 8, 0.5)
    assert proj.visible.tolist() == [True, False, False, False, False]
    assert np.allclose(proj.px[0], [320.0, 240.0])
    assert proj.right_u[0] == pytest.approx(320.0 - 500.0 * 0.1 / 5.0)
    assert proj.view_cos[0] == pytest.approx(1.0)
    assert proj.level[0] == int(predict_scale_level(5.0, 10.0, 1.2, 8))
