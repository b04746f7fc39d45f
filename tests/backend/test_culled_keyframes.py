"""Culled keyframes follow their spanning-tree parents' corrections (ORB-SLAM's Tcp chain)."""

import numpy as np

from zenslam.backend.culled_keyframes import CulledKeyframes
from zenslam.geometry import make_T, so3_exp


def _T(angle: float, t) -> np.ndarray:
    return make_T(so3_exp(np.array([0.0, angle, 0.0])), t)


def test_a_culled_keyframe_moves_with_its_parent_and_chains_through_culled_parents():
    poses = {0: np.eye(4), 1: _T(0.1, [1.0, 0, 0]), 2: _T(0.2, [2.0, 0, 0]), 3: _T(0.3, [3.0, 0, 0])}
    culled = CulledKeyframes()
    culled.record(2, 20, 1, poses[1], poses[2])  # 2 culled under 1
    culled.record(1, 10, 0, poses[0], poses[1])  # then 1 under 0
    culled.record(3, 30, 2, poses[2], poses[3])  # 3 was a child of 2 when culled
    correction = _T(0.5, [0.0, 4.0, 0.0])
    ids, stamps, T = culled.poses({0: correction @ poses[0]})
    np.testing.assert_array_equal(ids, [1, 2, 3])
    np.testing.assert_array_equal(stamps, [10, 20, 30])
    for row, k in enumerate([1, 2, 3]):
        np.testing.assert_allclose(T[row], correction @ poses[k], atol=1e-12)


def test_no_culled_keyframe_gives_empty_arrays():
    ids, stamps, T = CulledKeyframes().poses({0: np.eye(4)})
    assert ids.shape == (0,) and stamps.shape == (0,) and T.shape == (0, 4, 4)
