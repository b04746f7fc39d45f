"""Triangulation of new points: epipolar matching, linear / stereo triangulation and ORB-SLAM's checks."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.backend.triangulation import (
    TriangulationConfig,
    _node_runs,
    candidate_pairs,
    create_new_points,
    fundamental_matrix,
    match_for_triangulation,
    triangulate_matches,
    triangulate_pairs,
)
from zenslam.camera import PinholeCalibration
from zenslam.geometry import invert_T, make_T, so3_exp, transform_points
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE

CAL = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)
CONFIG = TriangulationConfig()


def view(kf_id: int, T_world_cam: np.ndarray, p_world: np.ndarray, descriptors: np.ndarray, rng, stereo=False, levels=None):
    """A keyframe whose keypoints are the exact projections of ``p_world`` (shuffled), with a few
    flipped descriptor bits; returns it and the point index of each keypoint."""
    order = rng.permutation(len(p_world))
    p_cam = transform_points(invert_T(T_world_cam), p_world[order])
    px = CAL.fx * p_cam[:, :2] / p_cam[:, 2:] + [CAL.cx, CAL.cy]
    desc = descriptors[order].copy()
    desc[np.arange(len(order)), rng.integers(0, 32, len(order))] ^= np.uint8(1)
    n = len(order)
    kf = BackendKeyframe(
        id=kf_id, stamp_ns=kf_id, T_world_cam=T_world_cam, calibration=CAL, sensor="stereo" if stereo else "mono",
        keypoints_px=px, levels=np.zeros(n, np.int64) if levels is None else levels[order], angles_deg=np.zeros(n),
        right_u=px[:, 0] - CAL.bf / p_cam[:, 2] if stereo else np.full(n, -1.0),
        depth_m=p_cam[:, 2].copy() if stereo else np.full(n, -1.0),
        descriptors=desc, scale_factors=1.2 ** np.arange(8), map_point_ids=np.full(n, -1, np.int64),
    )  # fmt: skip
    return kf, order


def scene(n: int = 120, seed: int = 1):
    rng = np.random.default_rng(seed)
    p_world = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(4, 10, n)])
    descriptors = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    T1 = make_T(np.eye(3), [0.0, 0.0, 0.0])
    T2 = make_T(so3_exp([0.0, 0.05, 0.0]), [0.6, 0.1, 0.2])
    return rng, p_world, descriptors, T1, T2


def test_fundamental_matrix_satisfies_the_epipolar_constraint() -> None:
    rng, p, d, T1, T2 = scene(20)
    kf1, o1 = view(0, T1, p, d, rng)
    kf2, o2 = view(1, T2, p, d, rng)
    F12 = fundamental_matrix(kf1, kf2)
    x1 = np.column_stack([kf1.keypoints_px[np.argsort(o1)], np.ones(20)])
    x2 = np.column_stack([kf2.keypoints_px[np.argsort(o2)], np.ones(20)])
    lines = x1 @ F12
    distance = np.abs(np.sum(lines * x2, axis=1)) / np.linalg.norm(lines[:, :2], axis=1)
    assert distance.max() < 1e-9  # pixels


def test_matching_pairs_keypoints_of_the_same_point() -> None:
    rng, p, d, T1, T2 = scene()
    kf1, o1 = view(0, T1, p, d, rng)
    kf2, o2 = view(1, T2, p, d, rng)
    idx1, idx2 = match_for_triangulation(kf1, kf2, fundamental_matrix(kf1, kf2), CONFIG)
    assert len(idx1) >= 0.95 * len(p)
    assert np.array_equal(o1[idx1], o2[idx2])  # every match is right
    assert len(set(idx2.tolist())) == len(idx2)  # one-to-one


def test_matching_skips_keypoints_that_already_have_a_point() -> None:
    rng, p, d, T1, T2 = scene()
    kf1, _ = view(0, T1, p, d, rng)
    kf2, _ = view(1, T2, p, d, rng)
    kf1.map_point_ids[:60] = 7
    idx1, _ = match_for_triangulation(kf1, kf2, fundamental_matrix(kf1, kf2), CONFIG)
    assert idx1.min() >= 60


def test_linear_triangulation_recovers_points_within_a_millimetre() -> None:
    rng, p, d, T1, T2 = scene()
    kf1, o1 = view(0, T1, p, d, rng)
    kf2, o2 = view(1, T2, p, d, rng)
    idx1, idx2 = match_for_triangulation(kf1, kf2, fundamental_matrix(kf1, kf2), CONFIG)
    result = triangulate_matches(kf1, kf2, idx1, idx2, CONFIG)
    assert result.ok.all()
    assert np.abs(result.p_world - p[o1[idx1]]).max() < 1e-3  # metres


def test_rejects_points_behind_inconsistent_with_the_epipolar_geometry_or_the_scale() -> None:
    rng = np.random.default_rng(0)
    p = np.array([[0.0, 0.0, 5.0], [0.3, 0.2, 6.0], [-0.4, 0.1, 7.0], [0.2, -0.3, 5.5]])
    d = rng.integers(0, 256, (4, 32), dtype=np.uint8)
    kf1, o1 = view(0, np.eye(4), p, d, rng)
    kf2, o2 = view(1, make_T(np.eye(3), [0.5, 0.0, 0.0]), p, d, rng)
    idx1, idx2 = np.argsort(o1), np.argsort(o2)  # keypoint of point i in each keyframe
    assert triangulate_matches(kf1, kf2, idx1, idx2, CONFIG).ok.all()
    # point 0: mirror its disparity so the rays meet behind the cameras
    kf2.keypoints_px[idx2[0], 0] = 2 * CAL.cx - kf2.keypoints_px[idx2[0], 0]
    # point 1: 20 px off the epipolar line: the two rays miss each other, reprojection fails
    kf2.keypoints_px[idx2[1], 1] += 20.0
    # point 2: seen at level 5 in kf2 from the same distance: scale inconsistent
    kf2.levels[idx2[2]] = 5
    ok = triangulate_matches(kf1, kf2, idx1, idx2, CONFIG).ok
    assert ok.tolist() == [False, False, False, True]


def test_low_parallax_with_stereo_depth_back_projects_instead() -> None:
    rng = np.random.default_rng(0)
    p = np.array([[0.5, 0.2, 20.0]])
    d = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    kf1, _ = view(0, np.eye(4), p, d, rng, stereo=True)
    kf2, _ = view(1, make_T(np.eye(3), [0.02, 0.0, 0.0]), p, d, rng, stereo=True)
    kf1.depth_m[0] = 20.1  # the stereo depth is what the point is built from
    result = triangulate_matches(kf1, kf2, np.array([0]), np.array([0]), CONFIG)
    np.testing.assert_allclose(result.p_world[0], kf1.unproject(np.array([0]))[0], atol=1e-12)
    assert result.p_world[0, 2] == pytest.approx(20.1)


def two_keyframe_map(stereo: bool, T2: np.ndarray, n: int = 120, shared: int = 30):
    """A map of two keyframes sharing ``shared`` points; the other ``n - shared`` are unmatched."""
    rng, p, d, T1, _ = scene(n)
    kf1, o1 = view(0, T1, p, d, rng, stereo=stereo)
    kf2, o2 = view(1, T2, p, d, rng, stereo=stereo)
    bmap = BackendMap()
    kf1.map_point_ids[np.argsort(o1)[:shared]] = np.arange(shared)
    for i in range(shared):
        bmap.add_point(i, p[i], 0)
    bmap.add_keyframe(kf1)
    kf2.map_point_ids[np.argsort(o2)[:shared]] = np.arange(shared)
    bmap.add_keyframe(kf2)
    return bmap, p, o1


def test_create_new_points_adds_observed_points_with_backend_ids() -> None:
    bmap, p, o1 = two_keyframe_map(stereo=False, T2=scene()[4])
    created = create_new_points(bmap, 1, CONFIG)
    assert len(created) >= 0.95 * 90
    assert min(created) == BACKEND_POINT_ID_BASE
    kf0 = bmap.keyframes[0]
    for point_id in created:
        pt = bmap.points[point_id]
        assert set(pt.observations) == {0, 1}
        truth = p[o1[pt.observations[0]]]
        assert np.linalg.norm(pt.p_world - truth) < 1e-3
        assert kf0.map_point_ids[pt.observations[0]] == point_id
    assert bmap.covisibility.weight(0, 1) == 30 + len(created)
    assert bmap.check_consistency() == []


def test_stereo_neighbours_closer_than_the_stereo_baseline_are_skipped() -> None:
    bmap, _, _ = two_keyframe_map(stereo=True, T2=make_T(np.eye(3), [0.05, 0.0, 0.0]))
    assert create_new_points(bmap, 1, CONFIG) == []


def test_pairs_with_several_keyframes_triangulate_as_each_keyframe_alone() -> None:
    rng, p, d, T1, T2 = scene(80, seed=4)
    kf1, _ = view(0, T1, p, d, rng, stereo=True)
    kf2, _ = view(1, T2, p, d, rng, stereo=True)
    kf3, _ = view(2, make_T(so3_exp([0.02, -0.04, 0.0]), [-0.5, 0.05, 0.3]), p, d, rng)
    pairs = [match_for_triangulation(kf1, k, fundamental_matrix(kf1, k), CONFIG) for k in (kf2, kf3)]
    which = np.repeat([0, 1], [len(pairs[0][0]), len(pairs[1][0])])
    idx1, idx2 = (np.concatenate(a) for a in zip(*pairs))
    mixed = rng.permutation(len(which))  # pairs of both keyframes interleaved
    together = triangulate_pairs(kf1, [kf2, kf3], which[mixed], idx1[mixed], idx2[mixed], CONFIG)
    alone = [triangulate_matches(kf1, k, i1, i2, CONFIG) for k, (i1, i2) in zip((kf2, kf3), pairs)]
    p_world = np.concatenate([a.p_world for a in alone])[mixed]
    ok = np.concatenate([a.ok for a in alone])[mixed]
    assert ok.sum() > 100
    assert together.ok.tolist() == ok.tolist()
    assert together.p_world[ok].tobytes() == p_world[ok].tobytes()


def test_each_neighbour_triangulates_from_the_keypoints_the_previous_ones_left() -> None:
    """Two neighbours seeing the same points: the first (strongest) gets most of them, the second
    only keypoints the first left free."""
    rng, p, d, T1, T2 = scene(100, seed=5)
    kf0, o0 = view(0, T1, p, d, rng)
    kf1, o1 = view(1, T2, p, d, rng)
    kf2, o2 = view(2, make_T(so3_exp([0.0, -0.05, 0.0]), [-0.6, 0.1, 0.2]), p, d, rng)
    bmap = BackendMap()
    for i in range(40):
        bmap.add_point(i, p[i], 0)
    shared = {0: (kf0, o0, 40), 1: (kf1, o1, 40), 2: (kf2, o2, 20)}  # keyframe 1 shares most with 0
    for kf, o, n in shared.values():
        kf.map_point_ids[np.argsort(o)[:n]] = np.arange(n)
        bmap.add_keyframe(kf)
    assert bmap.covisibility.best_covisible(0, 10) == [1, 2]
    created = create_new_points(bmap, 0, CONFIG)
    by_neighbour = {k: [c for c in created if k in bmap.points[c].observations] for k in (1, 2)}
    assert len(by_neighbour[1]) >= 50 and len(by_neighbour[2]) <= 60 - len(by_neighbour[1])
    assert bmap.check_consistency() == []  # among others: no keypoint of keyframe 0 observes two points


def _pairs(runs) -> list[tuple[int, int]]:
    order2, first, count = runs
    return [(r, int(order2[k])) for r in range(len(first)) for k in range(first[r], first[r] + count[r])]


def test_node_runs_are_every_pair_under_one_node_in_row_order() -> None:
    rng = np.random.default_rng(3)
    nodes1, nodes2 = rng.integers(-1, 6, 40), rng.integers(-1, 6, 50)
    expected = [(i, j) for i in range(40) for j in range(50) if nodes1[i] == nodes2[j] >= 0]
    assert _pairs(_node_runs(nodes1, nodes2)) == expected
    assert _pairs(_node_runs(nodes1, np.full(5, -1))) == []
    assert _node_runs(nodes1, nodes2, max_pairs=len(expected)) is not None
    assert _node_runs(nodes1, nodes2, max_pairs=len(expected) - 1) is None


def test_keypoints_are_paired_only_under_the_same_vocabulary_node() -> None:
    """With every keypoint under one node, the nodes change nothing; with the points' keypoints split
    between two nodes by point, only the pairs under one node remain, and each is still right."""
    rng, p, d, T1, T2 = scene()
    kf1, o1 = view(0, T1, p, d, rng)
    kf2, o2 = view(1, T2, p, d, rng)
    F12 = fundamental_matrix(kf1, kf2)
    idx1, idx2 = np.arange(kf1.n_keypoints), np.arange(kf2.n_keypoints)
    dense = candidate_pairs(kf1, kf2, idx1, idx2, F12, CONFIG)
    one_node = candidate_pairs(kf1, kf2, idx1, idx2, F12, CONFIG, (np.zeros(len(idx1), np.int64), np.zeros(len(idx2), np.int64)))
    assert all(a.tolist() == b.tolist() for a, b in zip(dense, one_node))
    # keypoints of points 0-59 under node 3, the others under 7; kf2's of points 50-59 under 7
    node1 = np.where(o1 < 60, 3, 7)
    node2 = np.where(o2 < 50, 3, 7)
    i1, i2, _ = candidate_pairs(kf1, kf2, idx1, idx2, F12, CONFIG, (node1, node2))
    kept = [(a, b) for a, b in zip(*dense[:2]) if node1[a] == node2[b]]
    assert list(zip(i1.tolist(), i2.tolist())) == kept
    assert len(kept) < len(dense[0])
    # More pairs under one node than a block of the dense test holds: the dense test, kept to nodes.
    few_rows = TriangulationConfig(block_rows=8)
    assert _node_runs(node1, node2, max_pairs=few_rows.block_rows * len(idx2)) is None
    blocked = candidate_pairs(kf1, kf2, idx1, idx2, F12, few_rows, (node1, node2))
    assert list(zip(blocked[0].tolist(), blocked[1].tolist())) == kept
    matched_points = set(o1[i1[o1[i1] == o2[i2]]].tolist())
    assert matched_points == set(range(120)) - set(range(50, 60))  # a point split between nodes is lost


def test_create_new_points_asks_each_keyframe_for_its_feature_nodes() -> None:
    bmap, _, _ = two_keyframe_map(stereo=False, T2=scene()[4])
    asked = []

    def one_node(kf_id, descriptors):
        asked.append(kf_id)
        return np.zeros(len(descriptors), np.int64)

    created = create_new_points(bmap, 1, CONFIG, one_node)
    assert sorted(asked) == [0, 1] and len(created) >= 0.95 * 90
    assert create_new_points(bmap, 1, CONFIG, lambda kf_id, descriptors: np.full(len(descriptors), -1)) == []
