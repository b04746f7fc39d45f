"""The frontend's local map: ids, observations, covisibility, local keyframes and points."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.frontend.id_allocator import IdAllocator
from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.local_map import LocalMap, LocalMapConfig
from zenslam.frontend.local_window import local_point_rows, local_window
from zenslam.frontend.map_sync import apply_map_update
from zenslam.frontend.orb_extractor import Features
from zenslam.geometry import make_T
from zenslam.map_point_rules import representative_descriptor
from zenslam.map_rules_config import MapRulesConfig
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE, KeyframeCorrection, MapUpdate


def add_keyframe(
    local_map: LocalMap,
    observed_ids: list[int] | np.ndarray,
    n_new: int,
    centre=(0.0, 0.0, 0.0),
    rng: np.random.Generator | None = None,
    descriptors: np.ndarray | None = None,
) -> KeyFrame:
    """Insert a keyframe whose first keypoints observe ``observed_ids`` and the next ``n_new`` make new points."""
    rng = rng or np.random.default_rng(0)
    observed_ids = np.asarray(observed_ids, dtype=np.int64)
    n = len(observed_ids) + n_new
    new_ids = local_map.new_point_ids(n_new)
    new_kps = np.arange(len(observed_ids), n, dtype=np.int64)
    T_world_cam = make_T(np.eye(3), np.asarray(centre, dtype=float))
    new_points = np.asarray(centre) + np.column_stack(
        [rng.uniform(-2, 2, n_new), rng.uniform(-1, 1, n_new), rng.uniform(4, 8, n_new)]
    )
    kf = KeyFrame(
        id=local_map.new_keyframe_id(),
        frame_index=local_map.n_keyframes,
        stamp_ns=local_map.n_keyframes * 100_000_000,
        T_world_cam=T_world_cam,
        features=Features(
            px=rng.uniform(0, 600, (n, 2)).astype(np.float32),
            level=np.zeros(n, dtype=np.int16),
            angle_deg=np.zeros(n, dtype=np.float32),
            response=np.ones(n, dtype=np.float32),
            descriptors=descriptors if descriptors is not None else rng.integers(0, 256, (n, 32), dtype=np.uint8),
            scale_factors=1.2 ** np.arange(8),
            inv_level_sigma2=1.2 ** (-2.0 * np.arange(8)),
        ),
        right_u=np.full(n, -1, dtype=np.float32),
        depth_m=np.full(n, -1, dtype=np.float32),
        map_point_ids=np.concatenate([observed_ids, new_ids]),
        new_point_ids=new_ids,
        new_point_keypoints=new_kps,
        new_points_world=new_points,
    )
    local_map.insert_keyframe(kf)
    return kf


def test_id_allocator_and_configured_id_spaces() -> None:
    alloc = IdAllocator(start=5, step=3)
    assert alloc.next() == 5
    assert alloc.take(3).tolist() == [8, 11, 14]
    assert alloc.next() == 17
    high = 1 << 62
    lm = LocalMap(LocalMapConfig(point_id_start=high, point_id_step=2, keyframe_id_start=1000))
    kf = add_keyframe(lm, [], 3)
    assert kf.id == 1000
    assert kf.new_point_ids.tolist() == [high, high + 2, high + 4]
    assert lm.point_ids.tolist() == kf.new_point_ids.tolist()
    assert lm.rows_of_ids(np.array([high + 2, 7, -1])).tolist() == [1, -1, -1]


def test_covisibility_weights_count_shared_points() -> None:
    lm = LocalMap()
    kf0 = add_keyframe(lm, [], 100)  # points 0..99
    kf1 = add_keyframe(lm, np.arange(0, 60), 50)  # new points 100..149
    add_keyframe(lm, np.concatenate([np.arange(40, 80), kf1.new_point_ids[:20]]), 10)
    assert lm.covisibility_weight(0, 1) == 60
    assert lm.covisibility_weight(0, 2) == 40
    assert lm.covisibility_weight(1, 2) == 20 + 20  # points 40..59 and 20 of kf1's new ones
    assert lm.covisibility_weight(1, 0) == 60  # symmetric
    assert lm.best_covisible(2, 10) == [0, 1]  # tie broken by slot
    assert lm.best_covisible(0, 10) == [1, 2]
    assert lm.parent(0) == -1 and lm.parent(1) == 0 and lm.parent(2) == 0
    assert lm.children(0) == [1, 2]
    assert lm.n_observations[:100].tolist() == [2] * 40 + [3] * 20 + [2] * 20 + [1] * 20
    assert lm.observations(45) == {kf0.id: 45, kf1.id: 45, 2: 5}


def test_weak_links_are_not_covisibility_edges_unless_the_only_one() -> None:
    lm = LocalMap(LocalMapConfig(map_rules=MapRulesConfig(min_covisibility_weight=15)))
    add_keyframe(lm, [], 100)
    add_keyframe(lm, np.arange(0, 10), 50)  # weight 10 < 15: still the only link -> kept
    add_keyframe(lm, np.concatenate([np.arange(20, 50), np.arange(100, 105)]), 0)  # 30 to kf0, 5 to kf1
    assert lm.best_covisible(1, 10) == [0]
    assert lm.best_covisible(2, 10) == [0]  # kf1's 5 shared points make no edge
    assert lm.covisibility_weight(2, 1) == 5


def test_local_window_votes_then_adds_one_neighbour_each() -> None:
    lm = LocalMap()
    add_keyframe(lm, [], 100)  # slot 0: points 0..99
    add_keyframe(lm, np.arange(0, 80), 100)  # slot 1: new 100..199
    add_keyframe(lm, np.arange(100, 170), 100)  # slot 2: new 200..299
    add_keyframe(lm, np.arange(200, 260), 100)  # slot 3: new 300..399
    add_keyframe(lm, np.arange(300, 350), 100)  # slot 4
    # A frame matched only to points first seen by slot 3 and also by slot 4 (300..349).
    frame_rows = lm.rows_of_ids(np.arange(300, 340))
    window = local_window(lm, np.concatenate([frame_rows, [-1, -1]]))
    assert window.reference_slot in (3, 4)
    voted = {3, 4}
    slots = window.keyframe_slots.tolist()
    assert set(slots[:2]) == voted
    # Each voted keyframe adds its first new best-covisible neighbour (slot 2 for slot 3) and its parent.
    assert 2 in slots
    assert len(slots) == len(set(slots))
    # Slot 0 is only a neighbour of neighbours: not local.
    assert 0 not in slots
    rows = local_point_rows(lm, window.keyframe_slots)
    assert np.all(np.diff(rows) > 0)
    expected = np.unique(np.concatenate([lm.keyframe_point_rows(s) for s in slots]))
    assert np.array_equal(rows, expected)


def test_local_window_reference_is_the_keyframe_sharing_most_points() -> None:
    lm = LocalMap()
    add_keyframe(lm, [], 100)
    add_keyframe(lm, np.arange(0, 30), 100)
    window = local_window(lm, lm.rows_of_ids(np.arange(0, 100)))
    assert window.reference_slot == 0
    assert window.keyframe_slots.tolist()[0] == 0
    empty = local_window(lm, np.full(5, -1))
    assert empty.reference_slot == -1 and len(empty.keyframe_slots) == 0


def test_local_window_stops_adding_neighbours_past_the_cap() -> None:
    lm = LocalMap(LocalMapConfig(max_local_keyframes=5))
    add_keyframe(lm, [], 200)
    for k in range(1, 12):  # every keyframe sees 20 points of slot 0 and one unique point
        add_keyframe(lm, np.arange(10 * k, 10 * k + 20), 1)
    # The frame sees one point of each of slots 1..8: all 8 are voted in, none added beyond.
    own_points = [200 + k - 1 for k in range(1, 9)]
    window = local_window(lm, lm.rows_of_ids(np.array(own_points)))
    assert sorted(window.keyframe_slots.tolist()) == list(range(1, 9))


def test_observations_refresh_descriptors_and_normals() -> None:
    rng = np.random.default_rng(4)
    lm = LocalMap()
    base = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    add_keyframe(lm, [], 1, centre=(0, 0, 0), rng=rng, descriptors=base)
    p = lm.p_world[0].copy()
    seen = [base[0]]
    centres = [np.zeros(3)]
    for k in range(1, 5):
        desc = rng.integers(0, 256, (1, 32), dtype=np.uint8)
        add_keyframe(lm, [0], 0, centre=(0.5 * k, 0, 0), rng=rng, descriptors=desc)
        seen.append(desc[0])
        centres.append(np.array([0.5 * k, 0, 0]))
    assert np.array_equal(lm.descriptors[0], representative_descriptor(np.stack(seen)))
    rays = p - np.stack(centres)
    expected = (rays / np.linalg.norm(rays, axis=1, keepdims=True)).mean(axis=0)
    assert np.allclose(lm.normals[0], expected, atol=1e-12)
    assert lm.n_observations[0] == 5
    # The distance range comes from the creating keyframe.
    d = np.linalg.norm(p)
    assert lm.max_distance_m[0] == pytest.approx(d)
    assert lm.min_distance_m[0] == pytest.approx(d / 1.2**7)


def test_map_update_hooks() -> None:
    lm = LocalMap()
    kf = add_keyframe(lm, [], 4)
    assert lm.set_point_positions(np.array([kf.new_point_ids[1], 999]), np.array([[1.0, 2, 3], [4, 5, 6]])) == 1
    assert lm.p_world[1].tolist() == [1.0, 2.0, 3.0]
    assert lm.remove_points(np.array([kf.new_point_ids[2]])) == 1
    assert lm.n_valid_points == 3
    # A keyframe naming a removed point does not observe it.
    add_keyframe(lm, kf.new_point_ids, 0)
    assert lm.n_observations.tolist() == [2, 2, 1, 2]


def _update(lm: LocalMap, point_ids, p_world, **kw) -> MapUpdate:
    """A MapUpdate replacing the listed points (positions given; other fields from the map or defaults)."""
    ids = np.asarray(point_ids, dtype=np.int64)
    n = len(ids)
    rows = lm.rows_of_ids(ids)
    known = rows >= 0
    desc = np.zeros((n, 32), np.uint8)
    desc[known] = lm.descriptors[rows[known]]
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    return MapUpdate(
        keyframe_id=kw.pop("keyframe_id", 0),
        stamp_ns=0,
        point_ids=ids,
        p_world=np.asarray(p_world, dtype=float).reshape(n, 3),
        descriptors=desc,
        normals=normals,
        min_distance_m=np.full(n, 0.5),
        max_distance_m=np.full(n, 20.0),
        **kw,
    )


def test_map_update_replaces_points_and_creates_backend_points() -> None:
    lm = LocalMap()
    kf0 = add_keyframe(lm, [], 20)
    backend_ids = BACKEND_POINT_ID_BASE + np.arange(4)
    associations = kf0.map_point_ids.copy()
    associations[17:20] = backend_ids[:3]  # kf0 observes three of them; none observes the fourth
    update = _update(
        lm, np.concatenate([kf0.new_point_ids[:2], backend_ids]), np.arange(18.0).reshape(6, 3),
        keyframes=(KeyframeCorrection(kf0.id, kf0.T_world_cam, associations),),
    )  # fmt: skip
    apply_map_update(lm, update)
    rows = lm.rows_of_ids(update.point_ids)
    assert np.all(rows[:5] >= 0) and rows[5] == -1 and lm.n_points == 23
    assert np.array_equal(lm.p_world[rows[:5]], update.p_world[:5])
    assert np.array_equal(lm.max_distance_m[rows[:5]], np.full(5, 20.0))
    assert lm.n_observations[rows[2:5]].tolist() == [1, 1, 1]


def test_map_update_replaces_keyframe_pose_and_associations() -> None:
    lm = LocalMap()
    kf0 = add_keyframe(lm, [], 50)
    kf1 = add_keyframe(lm, kf0.new_point_ids[:30], 20)
    backend_ids = BACKEND_POINT_ID_BASE + np.arange(25)
    moved = make_T(np.eye(3), np.array([0.1, 0.0, 0.0]))
    # kf1 now sees only 10 of kf0's points and 25 new backend points, which kf0 also sees.
    assoc1 = np.full(kf1.n_keypoints, -1, dtype=np.int64)
    assoc1[:10] = kf0.new_point_ids[:10]
    assoc1[30:50] = kf1.new_point_ids
    assoc1[10:30] = backend_ids[:20]
    assoc0 = kf0.map_point_ids.copy()
    assoc0[30:50] = backend_ids[:20]  # replaces 20 of kf0's own points
    update = _update(
        lm,
        backend_ids,
        np.tile([0.0, 0.0, 5.0], (25, 1)),
        keyframes=(KeyframeCorrection(kf1.id, moved, assoc1), KeyframeCorrection(kf0.id, np.eye(4), assoc0)),
        removed_point_ids=kf0.new_point_ids[30:50],
    )
    for _ in range(2):  # replacement semantics: applying twice changes nothing more
        apply_map_update(lm, update)
        assert np.allclose(lm.keyframe(1).T_world_cam, moved)
        assert np.array_equal(lm.keyframe(1).map_point_ids, assoc1)
        assert lm.covisibility_weight(0, 1) == 10 + 20
        assert lm.observations(int(lm.rows_of_ids([backend_ids[0]])[0])) == {kf0.id: 30, kf1.id: 10}
        assert lm.n_observations[lm.rows_of_ids(kf0.new_point_ids[10:30])].tolist() == [1] * 20
        assert not np.any(lm.valid[lm.rows_of_ids(kf0.new_point_ids[30:50])])
        assert lm.tracked_points(1, 2) == 30


def test_a_point_associated_with_two_keypoints_of_a_keyframe_is_observed_once_at_the_first() -> None:
    lm = LocalMap()
    kf0 = add_keyframe(lm, [], 30)
    kf1 = add_keyframe(lm, kf0.new_point_ids[:10], 10)
    assoc1 = kf1.map_point_ids.copy()
    assoc1[12] = assoc1[3]  # a damaged or merged association: the same point at keypoints 3 and 12
    assoc1[15] = kf0.new_point_ids[20]
    update = _update(lm, np.zeros(0, dtype=np.int64), np.zeros((0, 3)), keyframes=(KeyframeCorrection(kf1.id, np.eye(4), assoc1),))
    apply_map_update(lm, update)
    row = int(lm.rows_of_ids([assoc1[3]])[0])
    assert lm.observations(row) == {kf0.id: 3, kf1.id: 3}
    assert lm.n_observations[row] == 2
    assert lm.observations(int(lm.rows_of_ids([kf0.new_point_ids[20]])[0])) == {kf0.id: 20, kf1.id: 15}
    assert lm.covisibility_weight(0, 1) == 10 + 1


def test_keyframes_the_backend_has_not_mapped_follow_their_parents_correction() -> None:
    lm = LocalMap()
    kf0 = add_keyframe(lm, [], 40)
    kf1 = add_keyframe(lm, kf0.new_point_ids[:30], 20, centre=(0.0, 0.0, 1.0))
    kf2 = add_keyframe(lm, kf1.new_point_ids[:15], 20, centre=(0.0, 0.0, 2.0))
    assert (lm.parent(1), lm.parent(2)) == (0, 1)
    old_p = {kf.id: lm.p_world[lm.rows_of_ids(kf.new_point_ids)].copy() for kf in (kf0, kf1, kf2)}
    correction = make_T(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.array([0.1, 0.0, 0.0]))
    # The backend has mapped kf0 only: it moves kf0 and five of its points.
    update = _update(
        lm, kf0.new_point_ids[:5], np.zeros((5, 3)), keyframe_id=kf0.id,
        keyframes=(KeyframeCorrection(kf0.id, correction @ kf0.T_world_cam, kf0.map_point_ids),),
    )
    for _ in range(2):  # applying the update again moves nothing more
        apply_map_update(lm, update)
        for slot, kf in ((1, kf1), (2, kf2)):
            np.testing.assert_allclose(lm.keyframe(slot).T_world_cam, correction @ kf.T_world_cam, atol=1e-12)
            moved = old_p[kf.id] @ correction[:3, :3].T + correction[:3, 3]
            np.testing.assert_allclose(lm.p_world[lm.rows_of_ids(kf.new_point_ids)], moved, atol=1e-12)
        np.testing.assert_array_equal(lm.p_world[lm.rows_of_ids(kf0.new_point_ids[:5])], np.zeros((5, 3)))
        # kf0's other points are the backend's business: not listed, not moved.
        np.testing.assert_array_equal(lm.p_world[lm.rows_of_ids(kf0.new_point_ids[5:])], old_p[kf0.id][5:])


def test_a_correction_with_more_associations_than_keypoints_is_skipped(caplog) -> None:
    """A damaged correction naming a held keyframe with one association too many (or too few) is
    skipped with a warning: the keyframe keeps its pose and associations; the update's other
    keyframes and points are applied."""
    lm = LocalMap()
    kf0 = add_keyframe(lm, [], 40)
    kf1 = add_keyframe(lm, kf0.new_point_ids[:30], 20, centre=(0.0, 0.0, 1.0))
    moved = make_T(np.eye(3), np.array([0.0, 0.2, 0.0]))
    for damaged in (np.append(kf1.map_point_ids, -1), kf1.map_point_ids[:-1]):
        update = _update(
            lm, kf0.new_point_ids[:2], np.ones((2, 3)), keyframe_id=kf1.id,
            keyframes=(
                KeyframeCorrection(kf0.id, moved @ kf0.T_world_cam, kf0.map_point_ids),
                KeyframeCorrection(kf1.id, moved @ kf1.T_world_cam, damaged),
            ),
        )
        with caplog.at_level("WARNING", logger="zenslam.frontend.local_map"):
            apply_map_update(lm, update)
        assert f"keyframe {kf1.id}'s correction lists {len(damaged)} point associations for its 50 keypoints" in caplog.text
        np.testing.assert_array_equal(lm.keyframe(1).T_world_cam, kf1.T_world_cam)
        np.testing.assert_array_equal(lm.keyframe(1).map_point_ids, kf1.map_point_ids)
        np.testing.assert_allclose(lm.keyframe(0).T_world_cam, moved @ kf0.T_world_cam, atol=1e-12)
        np.testing.assert_array_equal(lm.p_world[lm.rows_of_ids(kf0.new_point_ids[:2])], np.ones((2, 3)))


def test_map_update_removes_keyframes() -> None:
    lm = LocalMap()
    kf0 = add_keyframe(lm, [], 40)
    kf1 = add_keyframe(lm, kf0.new_point_ids[:30], 40)
    add_keyframe(lm, kf1.new_point_ids[:30], 10)
    assert lm.parent(2) == 1
    apply_map_update(lm, _update(lm, [], np.zeros((0, 3)), removed_keyframe_ids=np.array([kf1.id])))
    assert lm.keyframe(1) is None and lm.slot_of(kf1.id) == -1
    assert lm.parent(2) == 0 and lm.children(0) == [2]
    assert lm.covisibility_weight(0, 1) == 0 and lm.best_covisible(2, 10) == []
    window = local_window(lm, lm.rows_of_ids(kf1.new_point_ids[:30]))
    assert window.keyframe_slots.tolist() == [2, 0]  # slot 2 voted, slot 0 its new parent
    assert lm.n_observations[lm.rows_of_ids(kf0.new_point_ids[:30])].tolist() == [1] * 30
