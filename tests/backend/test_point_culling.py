"""Recent map point culling: found ratio, too few observations after two keyframes, leaving the list."""

from __future__ import annotations

import numpy as np

from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.backend.point_culling import PointCullingConfig, count_visibility, cull_recent_points
from zenslam.camera import PinholeCalibration
from zenslam.geometry import make_T

CAL = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)
CONFIG = PointCullingConfig()


def keyframe(kf_id: int, n: int = 10, stereo: bool = False) -> BackendKeyframe:
    return BackendKeyframe(
        id=kf_id, stamp_ns=kf_id, T_world_cam=make_T(np.eye(3), [0.1 * kf_id, 0, 0]), calibration=CAL,
        sensor="stereo" if stereo else "mono", keypoints_px=np.full((n, 2), 300.0), levels=np.zeros(n, np.int64),
        angles_deg=np.zeros(n), right_u=np.full(n, 290.0 if stereo else -1.0), depth_m=np.full(n, 5.0 if stereo else -1.0),
        descriptors=np.zeros((n, 32), np.uint8), scale_factors=1.2 ** np.arange(8), map_point_ids=np.full(n, -1, np.int64),
    )  # fmt: skip


def grow(bmap: BackendMap, stereo: bool, n_keyframes: int) -> None:
    for k in range(len(bmap.keyframes), len(bmap.keyframes) + n_keyframes):
        bmap.add_keyframe(keyframe(k, stereo=stereo))


def test_found_ratio_below_a_quarter_is_culled() -> None:
    bmap = BackendMap()
    grow(bmap, False, 1)
    for p, (visible, found) in enumerate([(5, 1), (4, 1), (4, 2)]):
        pt = bmap.add_point(p, [0, 0, 5.0], 0)
        bmap.add_observation(p, 0, p)
        pt.n_visible, pt.n_found = visible, found
    keep, culled = cull_recent_points(bmap, [0, 1, 2], current_serial=0, monocular=False, config=CONFIG)
    assert culled == [0] and keep == [1, 2]  # 1/4 is not below a quarter
    assert 0 not in bmap.points and bmap.keyframes[0].map_point_ids[0] == -1


def test_observation_rule_applies_two_keyframes_after_creation_and_counts_stereo_twice() -> None:
    bmap = BackendMap()
    grow(bmap, True, 1)
    for p in range(3):
        bmap.add_point(p, [0, 0, 5.0], 0)  # created at serial 0
        bmap.add_observation(p, 0, p)  # one stereo observation: weighted 2
    grow(bmap, True, 1)
    bmap.add_observation(1, 1, 1)  # point 1: two stereo keyframes, weighted 4
    keep, culled = cull_recent_points(bmap, [0, 1, 2], current_serial=1, monocular=False, config=CONFIG)
    assert culled == [] and keep == [0, 1, 2]  # one keyframe later: too early to judge
    grow(bmap, True, 1)
    keep, culled = cull_recent_points(bmap, keep, current_serial=2, monocular=False, config=CONFIG)
    assert culled == [0, 2] and keep == [1]  # weighted 2 <= 3 for stereo
    grow(bmap, True, 1)
    keep, culled = cull_recent_points(bmap, keep, current_serial=3, monocular=False, config=CONFIG)
    assert culled == [] and keep == [] and 1 in bmap.points  # three keyframes old: leaves the list, stays in the map
    assert bmap.check_consistency() == []


def test_monocular_threshold_is_two_observations() -> None:
    bmap = BackendMap()
    grow(bmap, False, 3)
    for p, observers in enumerate([(0, 1), (0, 1, 2)]):
        bmap.add_point(p, [0, 0, 5.0], 0)
        for k in observers:
            bmap.add_observation(p, k, p)
        bmap.points[p].created_serial = 0
    _, culled = cull_recent_points(bmap, [0, 1], current_serial=2, monocular=True, config=CONFIG)
    assert culled == [0]  # 2 observations <= 2; 3 observations stay


def test_visibility_counts_views_and_finds() -> None:
    bmap = BackendMap()
    grow(bmap, False, 1)
    for p, z in enumerate([5.0, 6.0, -5.0]):
        bmap.add_point(p, [0.0, 0.0, z], 0)
        bmap.add_observation(p, 0, p)
    bmap.refresh_points()
    bmap.points[2].normal = np.array([0.0, 0.0, 1.0])
    kf = keyframe(1)
    kf.map_point_ids[0] = 0
    bmap.add_keyframe(kf)
    n = count_visibility(bmap, 1, [0, 1, 2, 77], CONFIG)
    assert n == 2
    assert [(bmap.points[p].n_visible, bmap.points[p].n_found) for p in range(3)] == [(2, 2), (2, 1), (1, 1)]
