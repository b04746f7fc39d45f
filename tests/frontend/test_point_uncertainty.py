"""A map point's covariance from the keyframes that observe it (``frontend.point_uncertainty``)."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.orb_extractor import Features
from zenslam.frontend.point_uncertainty import point_covariances
from zenslam.geometry import make_T, so3_exp

CAL = PinholeCalibration(fx=450.0, fy=440.0, cx=320.0, cy=240.0, width=640, height=480, baseline_m=0.12)
SCALES = 1.2 ** np.arange(8)


def keyframe(lm: LocalMap, T_world_cam: np.ndarray, p_world: np.ndarray, ids: np.ndarray | None, stereo: bool, level: int = 0) -> KeyFrame:
    """A keyframe seeing the points ``p_world`` (N, 3) exactly: new points when ``ids`` is None."""
    p_cam = (p_world - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]
    u = CAL.fx * p_cam[:, 0] / p_cam[:, 2] + CAL.cx
    v = CAL.fy * p_cam[:, 1] / p_cam[:, 2] + CAL.cy
    n = len(p_world)
    new = ids is None
    new_ids = lm.new_point_ids(n) if new else np.zeros(0, np.int64)
    kf = KeyFrame(
        id=lm.new_keyframe_id(), frame_index=lm.n_keyframes, stamp_ns=lm.n_keyframes, T_world_cam=T_world_cam,
        features=Features(
            px=np.column_stack([u, v]).astype(np.float32), level=np.full(n, level, np.int16), angle_deg=np.zeros(n, np.float32),
            response=np.ones(n, np.float32), descriptors=np.zeros((n, 32), np.uint8), scale_factors=SCALES,
            inv_level_sigma2=1.0 / SCALES**2,
        ),
        right_u=(u - CAL.bf / p_cam[:, 2] if stereo else np.full(n, -1.0)).astype(np.float32),
        depth_m=(p_cam[:, 2] if stereo else np.full(n, -1.0)).astype(np.float32),
        map_point_ids=new_ids if new else ids, new_point_ids=new_ids,
        new_point_keypoints=np.arange(n) if new else np.zeros(0, np.int64), new_points_world=p_world if new else np.zeros((0, 3)),
    )  # fmt: skip
    lm.insert_keyframe(kf)
    return kf


def test_one_stereo_observation_knows_depth_to_sigma_z_squared_over_bf() -> None:
    lm, z = LocalMap(), 6.0
    keyframe(lm, np.eye(4), np.array([[0.0, 0.0, z]]), None, stereo=True)
    cov = point_covariances(lm, np.array([0]), CAL, max_sigma_m=1e3)[0]
    # Along the ray only the disparity u - u_right = bf / z tells depth; u and u_right each carry
    # 1 px at level 0, so the disparity sqrt(2) px: sigma_z = sqrt(2) z^2 / bf. Across, x is u's
    # (u_right moves with it) and y is v's: z / f.
    assert np.sqrt(cov[2, 2]) == pytest.approx(np.sqrt(2) * z**2 / CAL.bf, rel=1e-3)
    assert np.sqrt(cov[0, 0]) == pytest.approx(z / CAL.fx, rel=1e-3)
    assert np.sqrt(cov[1, 1]) == pytest.approx(z / CAL.fy, rel=1e-3)


def test_more_observations_and_finer_levels_know_a_point_better() -> None:
    lm = LocalMap()
    p = np.array([[0.5, -0.2, 5.0], [0.1, 0.3, 7.0]])
    first = keyframe(lm, np.eye(4), p, None, stereo=True)
    rows = np.array([0, 1])
    one = point_covariances(lm, rows, CAL, max_sigma_m=1e3)
    keyframe(lm, np.eye(4), p[:1], first.new_point_ids[:1], stereo=True)  # the same view of point 0 again
    two = point_covariances(lm, rows, CAL, max_sigma_m=1e3)
    np.testing.assert_allclose(two[0], one[0] / 2, rtol=1e-5)
    np.testing.assert_allclose(two[1], one[1], rtol=1e-9)
    coarse = LocalMap()
    keyframe(coarse, np.eye(4), p, None, stereo=True, level=2)
    np.testing.assert_allclose(point_covariances(coarse, rows, CAL, max_sigma_m=1e3), one * SCALES[2] ** 2, rtol=1e-5)


def test_a_second_viewpoint_pins_the_depth_that_stereo_leaves_loose() -> None:
    lm = LocalMap()
    p = np.array([[0.0, 0.0, 8.0]])
    first = keyframe(lm, np.eye(4), p, None, stereo=True)
    along = point_covariances(lm, np.array([0]), CAL, max_sigma_m=1e3)[0][2, 2]
    side = make_T(so3_exp(np.array([0.0, -0.5, 0.0])), np.array([4.0, 0.0, 0.0]))  # 4 m to the right, turned to it
    keyframe(lm, side, p, first.new_point_ids, stereo=True)
    assert point_covariances(lm, np.array([0]), CAL, max_sigma_m=1e3)[0][2, 2] < 0.01 * along


def test_mono_only_and_unobserved_points_are_bounded_by_max_sigma() -> None:
    lm = LocalMap()
    keyframe(lm, np.eye(4), np.array([[0.0, 0.0, 5.0]]), None, stereo=False)
    cov = point_covariances(lm, np.array([0]), CAL, max_sigma_m=2.0)[0]
    assert np.sqrt(cov[2, 2]) == pytest.approx(2.0, rel=1e-3)  # one ray: nothing along it but the bound
    assert np.sqrt(cov[0, 0]) < 0.02
    empty = LocalMap()
    keyframe(empty, np.eye(4), np.zeros((0, 3)), None, stereo=False)
    assert point_covariances(empty, np.zeros(0, np.int64), CAL, max_sigma_m=2.0).shape == (0, 3, 3)
