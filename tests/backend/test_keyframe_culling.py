"""Keyframe culling: redundant when > 90% of its points are seen by 3+ others at the same or finer scale."""

from __future__ import annotations

import numpy as np

from zenslam.backend.keyframe_culling import KeyframeCullingConfig, cull_redundant_keyframes, is_redundant, redundant_keyframes
from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.camera import PinholeCalibration
from zenslam.geometry import make_T

CAL = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)
CONFIG = KeyframeCullingConfig()
N = 40


def keyframe(kf_id: int, point_ids: np.ndarray, level: int = 0, stereo: bool = False, depth: float = 2.0) -> BackendKeyframe:
    n = len(point_ids)
    return BackendKeyframe(
        id=kf_id, stamp_ns=kf_id, T_world_cam=make_T(np.eye(3), [0.1 * kf_id, 0, 0]), calibration=CAL,
        sensor="stereo" if stereo else "mono", keypoints_px=np.full((n, 2), 300.0), levels=np.full(n, level, np.int64),
        angles_deg=np.zeros(n), right_u=np.full(n, 290.0 if stereo else -1.0),
        depth_m=np.full(n, depth if stereo else -1.0), descriptors=np.zeros((n, 32), np.uint8),
        scale_factors=1.2 ** np.arange(8), map_point_ids=np.asarray(point_ids, dtype=np.int64).copy(),
    )  # fmt: skip


def build(levels=(0, 0, 0, 0, 0), stereo: bool = False, depth: float = 2.0, unique_in_2: int = 0) -> BackendMap:
    """Five keyframes over the same N points; keyframe 2 also has ``unique_in_2`` points nobody else sees."""
    bmap = BackendMap()
    for p in range(N + unique_in_2):
        bmap.add_point(p, [0, 0, 2.0], 0)
    for k, level in enumerate(levels):
        ids = np.arange(N + unique_in_2) if k == 2 else np.r_[np.arange(N), np.full(unique_in_2, -1)]
        bmap.add_keyframe(keyframe(k, ids, level, stereo, depth))
    return bmap


def test_keyframe_seen_through_by_three_others_is_culled_but_never_the_first() -> None:
    bmap = build()
    assert is_redundant(bmap, 2, CONFIG) and is_redundant(bmap, 0, CONFIG)
    culled, touched = cull_redundant_keyframes(bmap, 4, CONFIG)
    # connected to 4: 0, 1, 2, 3 (ties by id); 0 is the gauge; 1 goes; then 2 still has 0, 3, 4; then
    # 3 has only 0 and 4 left: kept
    assert culled == [1, 2]
    assert sorted(bmap.keyframes) == [0, 3, 4]
    assert set(touched) == set(range(N))
    assert bmap.check_consistency() == []
    assert bmap.spanning_tree.parent(3) == 0


def test_keyframe_with_its_own_points_is_kept() -> None:
    bmap = build(unique_in_2=6)  # 40 of 46 redundant: 87% < 90%
    assert not is_redundant(bmap, 2, CONFIG)
    assert is_redundant(build(unique_in_2=4), 2, CONFIG)  # 40 of 44: 91%


def test_other_views_must_be_at_the_same_or_a_finer_scale() -> None:
    assert not is_redundant(build(levels=(2, 2, 0, 2, 2)), 2, CONFIG)  # others two levels coarser
    assert is_redundant(build(levels=(1, 1, 0, 1, 1)), 2, CONFIG)  # one level coarser is allowed


def test_stereo_counts_only_close_points() -> None:
    assert is_redundant(build(stereo=True, depth=2.0), 2, CONFIG)
    assert not is_redundant(build(stereo=True, depth=5.0), 2, CONFIG)  # 5 m > 40 x 0.1 m: no close point


def test_loop_edge_keyframes_and_disabled_culling_are_left_alone() -> None:
    bmap = build()
    bmap.essential_graph.add_loop_edge(1, 3)
    culled, _ = cull_redundant_keyframes(bmap, 4, CONFIG)
    assert culled == [2]
    assert cull_redundant_keyframes(build(), 4, KeyframeCullingConfig(enabled=False)) == ([], [])


def _redundant_one_point_at_a_time(bmap: BackendMap, kf_id: int, config: KeyframeCullingConfig) -> bool:
    kf = bmap.keyframes[kf_id]
    keypoints = np.flatnonzero(kf.map_point_ids >= 0)
    if kf.sensor != "mono":
        depth = kf.depth_m[keypoints]
        keypoints = keypoints[(depth >= 0) & (depth <= config.close_depth_baselines * kf.calibration.baseline_m)]
    redundant = 0
    for keypoint in keypoints.tolist():
        pt = bmap.points[int(kf.map_point_ids[keypoint])]
        max_level = kf.levels[keypoint] + config.level_margin
        finer = [k for k, i in pt.observations.items() if k != kf_id and bmap.keyframes[k].levels[i] <= max_level]
        redundant += len(finer) >= config.min_other_observers
    return redundant > config.redundant_fraction * len(keypoints)


def test_all_candidates_at_once_agree_with_counting_each_point() -> None:
    rng = np.random.default_rng(3)
    bmap = BackendMap()
    for k in range(8):
        seen = rng.choice(60, size=45, replace=False)
        kf = keyframe(k, np.full(60, -1), stereo=k % 2 == 0, depth=float(rng.choice([2.0, 50.0])))
        kf.levels[:] = rng.integers(0, 4, 60)
        kf.map_point_ids[seen] = seen  # point i at keypoint i
        for p in seen.tolist():
            if p not in bmap.points:
                bmap.add_point(p, [0.0, 0.0, 2.0], k)
        bmap.add_keyframe(kf)
    config = KeyframeCullingConfig(redundant_fraction=0.6)
    ids = list(bmap.keyframes)
    expected = [_redundant_one_point_at_a_time(bmap, k, config) for k in ids]
    assert redundant_keyframes(bmap, ids, config).tolist() == expected
    assert any(expected) and not all(expected)
