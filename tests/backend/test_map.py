"""Backend map: observations mirrored both ways, graphs in step, merges, removals, derived point data."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.backend.map import BackendKeyframe, BackendMap, MapError, frustum_projection
from zenslam.camera import PinholeCalibration
from zenslam.geometry import make_T
from zenslam.map_point_rules import mean_viewing_direction, representative_descriptor, scale_invariance_range
from zenslam.schemas.codec import KeyframeMessage
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE

CAL = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)


def keyframe(kf_id: int, n: int = 50, x: float = 0.0, stereo: bool = False, seed: int = 0) -> BackendKeyframe:
    """A keyframe at (x, 0, 0) looking along +z with ``n`` random keypoints (no associations)."""
    rng = np.random.default_rng(seed + kf_id)
    return BackendKeyframe(
        id=kf_id,
        stamp_ns=kf_id * 1000,
        T_world_cam=make_T(np.eye(3), [x, 0.0, 0.0]),
        calibration=CAL,
        sensor="stereo" if stereo else "mono",
        keypoints_px=rng.uniform(0, 400, (n, 2)),
        levels=rng.integers(0, 3, n),
        angles_deg=np.zeros(n),
        right_u=rng.uniform(0, 300, n) if stereo else np.full(n, -1.0),
        depth_m=np.full(n, 5.0) if stereo else np.full(n, -1.0),
        descriptors=rng.integers(0, 256, (n, 32), dtype=np.uint8),
        scale_factors=1.2 ** np.arange(8),
        map_point_ids=np.full(n, -1, dtype=np.int64),
    )


def map_with_points(n_points: int = 40) -> BackendMap:
    bmap = BackendMap()
    bmap.add_keyframe(keyframe(0))
    for p in range(n_points):
        bmap.add_point(p, [p * 0.1, 0.0, 5.0], 0)
        bmap.add_observation(p, 0, p)
    return bmap


def add_observing(bmap: BackendMap, kf_id: int, point_ids: list[int], x: float = 0.0, stereo: bool = False) -> BackendKeyframe:
    kf = keyframe(kf_id, x=x, stereo=stereo)
    kf.map_point_ids[: len(point_ids)] = point_ids
    bmap.add_keyframe(kf)
    return kf


def test_keyframe_from_message_copies_arrays_and_starts_without_associations() -> None:
    n = 4
    msg = KeyframeMessage(
        id=7, stamp_ns=5, frame_index=3, T_world_cam=np.eye(4), calibration=CAL, sensor="stereo",
        keypoints_px=np.zeros((n, 2), np.float32), levels=np.arange(n, dtype=np.int16),
        angles_deg=np.zeros(n, np.float32), right_u=np.full(n, -1, np.float32), depth_m=np.full(n, -1, np.float32),
        descriptors=np.zeros((n, 32), np.uint8), map_point_ids=np.arange(n, dtype=np.int64),
        scale_factors=1.2 ** np.arange(8), new_point_ids=np.zeros(0, np.int64), new_points_world=np.zeros((0, 3)),
    )  # fmt: skip
    kf = BackendKeyframe.from_message(msg)
    assert kf.id == 7 and kf.levels.dtype == np.int64 and kf.levels.flags.writeable
    assert kf.map_point_ids.tolist() == [-1] * n
    assert kf.scale_factor == pytest.approx(1.2) and kf.n_levels == 8
    assert kf.level_sigma2[2] == pytest.approx(1.2**4)


def test_insertion_mirrors_observations_and_counts_covisibility() -> None:
    bmap = map_with_points()
    add_observing(bmap, 1, list(range(0, 30)), x=0.2)
    add_observing(bmap, 2, list(range(10, 40)), x=0.4)
    assert bmap.points[12].observations == {0: 12, 1: 12, 2: 2}
    assert bmap.keyframes[2].map_point_ids[2] == 12
    assert bmap.covisibility.weight(0, 1) == 30
    assert bmap.covisibility.weight(0, 2) == 30
    assert bmap.covisibility.weight(1, 2) == 20
    assert bmap.spanning_tree.parent(1) == 0
    assert bmap.spanning_tree.parent(2) == 0  # 30 shared with 0 beats 20 with 1
    assert bmap.first_keyframe_id == 0
    assert bmap.check_consistency() == []


def test_insertion_refuses_unknown_points_duplicates_and_reused_ids() -> None:
    bmap = map_with_points()
    with pytest.raises(MapError, match="unknown points \\[99\\]"):
        add_observing(bmap, 1, [99])
    with pytest.raises(MapError, match="one point twice"):
        add_observing(bmap, 1, [3, 3])
    add_observing(bmap, 1, [1, 2])
    with pytest.raises(MapError, match="already in the backend map"):
        add_observing(bmap, 1, [4])
    with pytest.raises(MapError, match="already observes"):
        bmap.add_observation(5, 1, 0)  # keypoint 0 of keyframe 1 holds point 1
    with pytest.raises(MapError, match="already observed"):
        bmap.add_observation(1, 1, 10)
    with pytest.raises(MapError, match="already used"):
        bmap.add_point(3, np.zeros(3), 1)


def test_weighted_observations_count_stereo_twice() -> None:
    bmap = map_with_points()
    add_observing(bmap, 1, [0, 1], x=0.2, stereo=True)
    assert bmap.points[0].weighted_observations == 3  # mono keyframe 0 + stereo keyframe 1
    bmap.remove_observation(0, 1)
    assert bmap.points[0].weighted_observations == 1
    assert bmap.keyframes[1].map_point_ids[0] == -1
    assert bmap.covisibility.weight(0, 1) == 1
    assert bmap.check_consistency() == []


def test_replace_point_merges_observations_and_keeps_the_survivor_keypoint() -> None:
    bmap = map_with_points()
    add_observing(bmap, 1, [0, 1], x=0.2)  # keyframe 1 sees 0 (keypoint 0) and 1 (keypoint 1)
    kf2 = add_observing(bmap, 2, [1], x=0.4)  # keyframe 2 sees 1 only
    bmap.replace_point(0, 1)
    assert 0 not in bmap.points and bmap.resolve(0) == 1
    # keyframe 0 moves to point 1 unless it already saw it: it did (keypoint 1), so keypoint 0 is freed
    assert bmap.points[1].observations == {0: 1, 1: 1, 2: 0}
    assert bmap.keyframes[0].map_point_ids[0] == -1 and bmap.keyframes[1].map_point_ids[0] == -1
    assert kf2.map_point_ids[0] == 1
    assert bmap.check_consistency() == []
    changes = bmap.take_changes()
    assert 0 in changes.removed_points and 1 in changes.points and {0, 1} <= changes.keyframes


def test_remove_point_and_weak_points() -> None:
    bmap = map_with_points()
    add_observing(bmap, 1, [0, 1, 2], x=0.2)
    bmap.remove_point(1)
    assert bmap.resolve(1) == -1 and bmap.covisibility.weight(0, 1) == 2
    removed = bmap.remove_weak_points([0, 3, 99], min_keyframes=2)
    assert removed == [3]  # 0 has two observers; 99 is unknown
    assert bmap.check_consistency() == []


def test_remove_keyframe_reparents_children_and_protects_the_first() -> None:
    bmap = map_with_points()
    add_observing(bmap, 1, list(range(0, 40)), x=0.2)
    add_observing(bmap, 2, list(range(0, 20)), x=0.4)  # parent 0 (tie 20/20 -> smaller id)
    add_observing(bmap, 3, list(range(20, 40)), x=0.6)  # parent 0 too
    bmap.spanning_tree.set_parent(3, 1)
    touched = bmap.remove_keyframe(1)
    assert touched == list(range(0, 40))
    assert bmap.spanning_tree.parent(3) == 0
    assert all(1 not in bmap.points[p].observations for p in range(40))
    assert 1 not in bmap.covisibility and bmap.check_consistency() == []
    assert bmap.take_changes().removed_keyframes == {1}
    with pytest.raises(MapError, match="first keyframe"):
        bmap.remove_keyframe(0)


def test_refresh_uses_the_shared_map_point_rules() -> None:
    bmap = map_with_points()
    kf1 = add_observing(bmap, 1, [5], x=1.0)
    kf2 = add_observing(bmap, 2, [5], x=-1.0)
    bmap.set_point_position(5, [0.5, 0.2, 6.0])
    bmap.refresh_points()
    pt = bmap.points[5]
    observed = np.stack([bmap.keyframes[0].descriptors[5], kf1.descriptors[0], kf2.descriptors[0]])
    assert np.array_equal(pt.descriptor, representative_descriptor(observed))
    centres = np.array([[0.0, 0, 0], [1.0, 0, 0], [-1.0, 0, 0]])
    np.testing.assert_allclose(pt.normal, mean_viewing_direction(pt.p_world, centres), atol=1e-12)
    lo, hi = scale_invariance_range(np.linalg.norm(pt.p_world), bmap.keyframes[0].levels[5], 1.2, 8)
    assert pt.min_distance_m == pytest.approx(lo) and pt.max_distance_m == pytest.approx(hi)


def test_new_points_take_backend_ids_and_are_logged_as_created() -> None:
    bmap = map_with_points(2)
    pt = bmap.new_point([0, 0, 3.0], 0)
    assert pt.id == BACKEND_POINT_ID_BASE and bmap.new_point([0, 0, 4.0], 0).id == BACKEND_POINT_ID_BASE + 1
    assert pt.id in bmap.take_changes().created_points
    assert bmap.take_changes().created_points == set()


def test_consistency_check_reports_a_broken_mirror() -> None:
    bmap = map_with_points(5)
    bmap.keyframes[0].map_point_ids[1] = -1  # tamper with one side only
    problems = bmap.check_consistency()
    assert any("point 1 -> keyframe 0" in p for p in problems)


def test_frustum_projection_applies_orb_slam_visibility_rules() -> None:
    bmap = map_with_points(3)
    kf = bmap.keyframes[0]
    bmap.refresh_points()
    pts = [bmap.points[p] for p in range(3)]
    pts[1].p_world = np.array([0.0, 0.0, -5.0])  # behind
    pts[2].p_world = np.array([0.0, 0.0, 500.0])  # beyond 1.2 x the max distance
    proj = frustum_projection(kf, pts)
    assert proj.visible.tolist() == [True, False, False]
    np.testing.assert_allclose(proj.px[0], [320.0, 240.0])
    assert proj.depth_m[0] == pytest.approx(5.0)


def test_refresh_of_many_points_matches_the_rules_point_by_point() -> None:
    """Points with 1 to 9 observations, some of them made out of keyframe-id order (merges), some
    no longer seen by the keyframe that created them: each gets what the rules give it alone."""
    rng = np.random.default_rng(7)
    bmap = BackendMap()
    kfs = [keyframe(k, n=60, x=0.3 * k, stereo=k % 2 == 1) for k in (0, 1, 2, 3, 4, 5, 6, 7, 8)]
    for kf in kfs:
        bmap.add_keyframe(kf)
    for p in range(40):
        observers = rng.choice(9, size=1 + p % 9, replace=False).tolist()  # in a random order
        creator = observers[-1] if p % 2 else (set(range(9)) - set(observers) or {observers[0]}).pop()
        bmap.add_point(p, [rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(4, 8)], first_keyframe_id=creator)
        for k in observers:
            bmap.add_observation(p, k, p)
    bmap.refresh_points()
    centres = {k: bmap.keyframes[k].centre_world for k in bmap.keyframes}
    for p, pt in bmap.points.items():
        observers = sorted(pt.observations)
        descriptors = np.stack([bmap.keyframes[k].descriptors[pt.observations[k]] for k in observers])
        assert np.array_equal(pt.descriptor, representative_descriptor(descriptors))
        normal = mean_viewing_direction(pt.p_world, np.stack([centres[k] for k in observers]))
        assert pt.normal.tobytes() == normal.tobytes()
        ref = pt.reference_keyframe_id
        distance = np.linalg.norm((pt.p_world - centres[ref])[None], axis=1)  # as for many points at once
        lo, hi = scale_invariance_range(distance, bmap.keyframes[ref].levels[pt.observations[ref]], 1.2, 8)
        assert (pt.min_distance_m, pt.max_distance_m) == (float(lo[0]), float(hi[0]))


def test_points_keep_their_values_when_the_store_is_compacted() -> None:
    bmap = BackendMap()
    bmap.add_keyframe(keyframe(0, n=1000))
    bmap.add_keyframe(keyframe(1, n=1000, x=0.2))
    for p in range(900):
        bmap.add_point(p, [p * 0.01, 0.0, 5.0], 0)
        bmap.add_observation(p, 0, p)
        bmap.add_observation(p, 1, p)
    bmap.refresh_points()
    removed = bmap.points[7]
    before = (removed.p_world.copy(), removed.descriptor.copy(), removed.normal.copy())
    survivors = {p: bmap.points[p].p_world.copy() for p in range(800, 900)}
    for p in range(800):
        bmap.remove_point(p)
    store = bmap.point_store
    for p in range(5000, 5000 + store.capacity - store.n_rows + 1):  # fills the store, then one more
        bmap.add_point(p, [0.0, 0.0, float(p)], 1)
    assert bmap.point_store is not store  # the live points moved to a compact store
    assert bmap.point_store.n_rows == len(bmap.points)
    assert all(np.array_equal(bmap.points[p].p_world, xyz) for p, xyz in survivors.items())
    assert np.array_equal(removed.p_world, before[0]) and np.array_equal(removed.normal, before[2])
    assert np.array_equal(removed.descriptor, before[1])
    assert bmap.check_consistency() == []  # the keyframes' point rows were remapped
    np.testing.assert_array_equal(bmap.positions([850, 5003]), [survivors[850], [0.0, 0.0, 5003.0]])


def test_batched_new_points_equal_one_by_one_insertion() -> None:
    one, batch = map_with_points(3), map_with_points(3)
    kf_one, kf_batch = add_observing(one, 1, [0, 1, 2]), add_observing(batch, 1, [0, 1, 2])
    p_world = np.array([[0.0, 1.0, 5.0], [1.0, 0.0, 6.0]])
    for point_id, p, keypoint in zip([50, 51], p_world, [10, 11]):
        one.add_point(point_id, p, 1)
        one.add_observation(point_id, 1, keypoint)
    batch.add_observed_points([50, 51], p_world, 1, [10, 11])
    assert kf_one.map_point_ids.tolist() == kf_batch.map_point_ids.tolist()
    assert batch.points[51].observations == one.points[51].observations == {1: 11}
    np.testing.assert_array_equal(batch.positions([50, 51]), p_world)
    assert batch.check_consistency() == [] and batch.take_changes().points == one.take_changes().points
    with pytest.raises(MapError, match="already"):
        batch.add_observed_points([52], p_world[:1], 1, [10])


def map_state(bmap: BackendMap) -> dict[str, object]:
    """Everything a saved map holds, the keyframes' point rows and the change log, for comparisons."""
    from zenslam.backend.map_arrays import map_to_arrays

    state: dict[str, object] = {k: v.tolist() for k, v in map_to_arrays(bmap, None).items()}
    state["point_order"] = list(bmap.points)
    state["map_point_rows"] = [kf.map_point_rows.tolist() for kf in bmap.keyframes.values()]
    state["covisibility_order"] = [list(bmap.covisibility.weights(k)) for k in bmap.keyframes]
    state["changes"] = vars(bmap.changes.copy())
    return state


def checkpoint_scene() -> BackendMap:
    """Keyframes 0 and 1 share points 0-39; keyframe 2 (at x = 1) sees 40-59 as duplicates 100-119,
    keyframe 3 sees 0-9 only; everything refreshed and the change log taken."""
    bmap = BackendMap()
    bmap.add_keyframe(keyframe(0, n=60))
    for p in range(60):
        bmap.add_point(p, [p * 0.1, 0.0, 5.0], 0)
        bmap.add_observation(p, 0, p)
    add_observing(bmap, 1, list(range(40)), x=0.2, stereo=True)
    for p in range(100, 120):
        bmap.add_point(p, [(p - 100) * 0.1, 0.0, 5.0], 1)
    add_observing(bmap, 2, list(range(100, 120)), x=1.0)
    add_observing(bmap, 3, list(range(10)), x=0.1)
    bmap.take_changes()
    return bmap


def test_a_checkpoint_puts_back_merges_new_observations_poses_and_positions() -> None:
    bmap = checkpoint_scene()
    bmap.set_point_position(55, [9.0, 9.0, 9.0])  # a pending change outside the scope stays pending
    before = map_state(bmap)
    scope = [*range(40, 60), *range(100, 120)]
    checkpoint = bmap.checkpoint(scope, [2])
    for p in range(100, 110):
        bmap.replace_point(p, p - 60)  # keyframe 2's duplicates merged into 40-49
    bmap.replace_point(50, 110)
    bmap.add_observation(59, 2, 30)
    bmap.set_keyframe_pose(2, make_T(np.eye(3), [1.5, 0.0, 0.0]))
    bmap.set_point_positions([111, 112], np.ones((2, 3)))
    bmap.refresh_points()
    assert map_state(bmap) != before
    bmap.restore(checkpoint)
    assert map_state(bmap) == before
    assert bmap.check_consistency() == []
    assert bmap.take_changes().points == {55}  # the change made before the checkpoint is still pending


def test_a_checkpoint_refuses_changes_outside_its_scope_and_changes_taken_since() -> None:
    bmap = checkpoint_scene()
    checkpoint = bmap.checkpoint(range(100, 120), [2])
    bmap.replace_point(5, 6)  # keyframes 0, 1 and 3 are outside the scope
    with pytest.raises(MapError, match=r"points \[5\] and keyframes \[0, 1, 3\] changed outside"):
        bmap.restore(checkpoint)
    checkpoint = bmap.checkpoint(range(100, 120), [2])
    bmap.replace_point(100, 40)
    bmap.take_changes()
    with pytest.raises(MapError, match="changes were taken or points added"):
        bmap.restore(checkpoint)
