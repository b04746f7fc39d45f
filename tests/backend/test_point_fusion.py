"""Point fusion: duplicates merged into one point with every observation, new observations added."""

from __future__ import annotations

import numpy as np

from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.backend.point_fusion import FusionConfig, fuse_with_neighbours, fusion_targets, match_by_projection
from zenslam.camera import PinholeCalibration
from zenslam.geometry import invert_T, make_T, transform_points

CAL = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)
CONFIG = FusionConfig()
N = 60


def world(seed: int = 3):
    rng = np.random.default_rng(seed)
    p = np.column_stack([rng.uniform(-2, 2, N), rng.uniform(-1.5, 1.5, N), rng.uniform(4, 8, N)])
    return rng, p, rng.integers(0, 256, (N, 32), dtype=np.uint8)


def view(kf_id: int, x: float, p: np.ndarray, d: np.ndarray, stereo: bool = False) -> BackendKeyframe:
    """Keyframe at (x, 0, 0) whose keypoint i is the exact projection of point i."""
    T = make_T(np.eye(3), [x, 0.0, 0.0])
    p_cam = transform_points(invert_T(T), p)
    px = CAL.fx * p_cam[:, :2] / p_cam[:, 2:] + [CAL.cx, CAL.cy]
    return BackendKeyframe(
        id=kf_id, stamp_ns=kf_id, T_world_cam=T, calibration=CAL, sensor="stereo" if stereo else "mono",
        keypoints_px=px, levels=np.zeros(N, np.int64), angles_deg=np.zeros(N),
        right_u=px[:, 0] - CAL.bf / p_cam[:, 2] if stereo else np.full(N, -1.0),
        depth_m=p_cam[:, 2].copy() if stereo else np.full(N, -1.0), descriptors=d.copy(),
        scale_factors=1.2 ** np.arange(8), map_point_ids=np.full(N, -1, np.int64),
    )  # fmt: skip


def two_views(duplicated: range, unassociated_in_b: range, stereo: bool = False):
    """Keyframes A (id 0) and B (id 1) over the same points; points in ``duplicated`` got a second
    id (100 + i) in B, those in ``unassociated_in_b`` no association in B."""
    _, p, d = world()
    bmap = BackendMap()
    a, b = view(0, 0.0, p, d, stereo), view(1, 0.3, p, d, stereo)
    for i in range(N):
        bmap.add_point(i, p[i], 0)
    a.map_point_ids[:] = np.arange(N)
    bmap.add_keyframe(a)
    ids_b = np.arange(N)
    ids_b[list(duplicated)] = 100 + np.asarray(duplicated)
    ids_b[list(unassociated_in_b)] = -1
    for i in duplicated:
        bmap.add_point(100 + i, p[i] + 0.002, 1)
    b.map_point_ids[:] = ids_b
    bmap.add_keyframe(b)
    bmap.refresh_points()
    return bmap, p


def test_duplicates_become_one_point_with_both_observations() -> None:
    bmap, p = two_views(duplicated=range(40, 50), unassociated_in_b=range(0))
    for i in range(40, 50):  # the duplicates only have B's observation
        assert bmap.points[100 + i].observations == {1: i}
    fused = fuse_with_neighbours(bmap, 1, CONFIG)
    assert fused == 10
    for i in range(40, 50):
        survivor = bmap.resolve(100 + i)
        assert survivor == bmap.resolve(i) and survivor >= 0
        assert bmap.points[survivor].observations == {0: i, 1: i}
    assert len(bmap.points) == N
    assert bmap.covisibility.weight(0, 1) == N
    assert bmap.check_consistency() == []
    changes = bmap.take_changes()
    assert len(changes.removed_points) == 10


def test_the_point_with_more_observations_survives() -> None:
    bmap, p = two_views(duplicated=range(40, 41), unassociated_in_b=range(0))
    c = view(2, -0.3, p, np.asarray([bmap.keyframes[0].descriptors[i] for i in range(N)]))
    c.map_point_ids[:] = np.arange(N)
    c.map_point_ids[40] = 140  # point 140 is now seen by B and C, point 40 by A only
    bmap.add_keyframe(c)
    bmap.refresh_points()
    fuse_with_neighbours(bmap, 0, CONFIG)
    assert 40 not in bmap.points and bmap.resolve(40) == 140
    assert bmap.points[140].observations == {0: 40, 1: 40, 2: 40}
    assert bmap.check_consistency() == []


def test_unassociated_keypoint_gets_the_projected_point() -> None:
    bmap, _ = two_views(duplicated=range(0), unassociated_in_b=range(10, 20))
    fuse_with_neighbours(bmap, 1, CONFIG)
    for i in range(10, 20):
        assert bmap.points[i].observations == {0: i, 1: i}
    assert bmap.covisibility.weight(0, 1) == N


def test_stereo_keypoints_are_gated_on_the_right_coordinate() -> None:
    bmap, _ = two_views(duplicated=range(0), unassociated_in_b=range(10, 20), stereo=True)
    kf_b = bmap.keyframes[1]
    kf_b.right_u[10:20] -= 10.0  # disparity wrong by 10 px: outside the 7.815 gate at level 0
    fuse_with_neighbours(bmap, 1, CONFIG)
    assert all(1 not in bmap.points[i].observations for i in range(10, 20))


def test_descriptor_far_from_the_point_is_not_matched() -> None:
    bmap, _ = two_views(duplicated=range(0), unassociated_in_b=range(10, 20))
    kf_b = bmap.keyframes[1]
    kf_b.descriptors[10:20] ^= np.uint8(0xFF)  # 256 bits apart
    pts = [bmap.points[i] for i in range(10, 20)]
    rows, keypoints = match_by_projection(kf_b, pts, CONFIG)
    assert len(rows) == 0


def test_targets_are_first_then_second_neighbours_each_once() -> None:
    bmap, p = two_views(duplicated=range(0), unassociated_in_b=range(0))
    c = view(2, 0.6, p, bmap.keyframes[0].descriptors)
    c.map_point_ids[:20] = np.arange(20)
    bmap.add_keyframe(c)
    assert fusion_targets(bmap, 0, CONFIG) == [1, 2]
    assert fusion_targets(bmap, 2, CONFIG) == [0, 1]
