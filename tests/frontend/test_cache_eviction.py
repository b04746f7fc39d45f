"""Eviction from the frontend's map cache: the window and margin stay, the rest goes, ids stay consistent."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from zenslam.errors import ConfigError
from zenslam.frontend.cache_eviction import CacheEviction, keyframes_to_keep
from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.local_map import LocalMap, LocalMapConfig
from zenslam.frontend.map_sync import apply_map_update
from zenslam.frontend.local_window import local_window
from zenslam.frontend.orb_extractor import Features
from zenslam.geometry import make_T
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE, KeyframeCorrection, MapUpdate

SHARED = 30  # points a keyframe of the corridor shares with the previous one
NEW = 40  # points each keyframe of the corridor creates


def corridor_keyframe(lm: LocalMap, observed_ids: np.ndarray, n_new: int, x_m: float) -> KeyFrame:
    """A keyframe at (x_m, 0, 0) observing ``observed_ids`` with its first keypoints and making ``n_new`` points."""
    rng = np.random.default_rng(lm.n_keyframes)
    n = len(observed_ids) + n_new
    new_ids = lm.new_point_ids(n_new)
    centre = np.array([x_m, 0.0, 0.0])
    kf = KeyFrame(
        id=lm.new_keyframe_id(),
        frame_index=lm.n_keyframes,
        stamp_ns=lm.n_keyframes * 100_000_000,
        T_world_cam=make_T(np.eye(3), centre),
        features=Features(
            px=rng.uniform(0, 600, (n, 2)).astype(np.float32),
            level=np.zeros(n, dtype=np.int16),
            angle_deg=np.zeros(n, dtype=np.float32),
            response=np.ones(n, dtype=np.float32),
            descriptors=rng.integers(0, 256, (n, 32), dtype=np.uint8),
            scale_factors=1.2 ** np.arange(8),
            inv_level_sigma2=1.2 ** (-2.0 * np.arange(8)),
        ),
        right_u=np.full(n, -1, dtype=np.float32),
        depth_m=np.full(n, -1, dtype=np.float32),
        map_point_ids=np.concatenate([observed_ids, new_ids]).astype(np.int64),
        new_point_ids=new_ids,
        new_point_keypoints=np.arange(len(observed_ids), n, dtype=np.int64),
        new_points_world=centre + rng.uniform([-2, -1, 4], [2, 1, 8], (n_new, 3)),
    )
    lm.insert_keyframe(kf)
    return kf


def corridor(n_keyframes: int, config: LocalMapConfig) -> tuple[LocalMap, list[KeyFrame]]:
    """Keyframes 1 m apart along x, each seeing SHARED of the previous one's new points: a chain of
    covisibility with nothing shared two keyframes apart."""
    lm = LocalMap(config)
    keyframes = [corridor_keyframe(lm, np.zeros(0, dtype=np.int64), NEW, 0.0)]
    for k in range(1, n_keyframes):
        keyframes.append(corridor_keyframe(lm, keyframes[-1].new_point_ids[:SHARED], NEW, float(k)))
    return lm, keyframes


def frame_rows_seeing(lm: LocalMap, keyframe: KeyFrame) -> np.ndarray:
    """Map rows per keypoint of a frame matched to the points ``keyframe`` observes."""
    return lm.rows_of_ids(keyframe.map_point_ids)


def cached_ids(lm: LocalMap) -> list[int]:
    return [lm.keyframe(int(s)).id for s in lm.cached_slots()]


CONFIG = LocalMapConfig(cache_max_keyframes=10, cache_margin_keyframes=2, cache_min_keyframes_between_evictions=1)


def test_eviction_keeps_the_window_and_margin_and_drops_the_rest() -> None:
    lm, keyframes = corridor(20, CONFIG)
    rows = frame_rows_seeing(lm, keyframes[-1])
    window_ids = [keyframes[s].id for s in local_window(lm, rows).keyframe_slots.tolist()]
    assert sorted(window_ids) == [17, 18, 19]  # voted 18, 19 (SHARED of 19's points); 18's parent 17
    before = {kf.id: lm.point_ids[lm.keyframe_point_rows(lm.slot_of(kf.id))].copy() for kf in keyframes}
    p_before = dict(zip(lm.point_ids.tolist(), lm.p_world.copy()))
    weight = lm.covisibility_weight(lm.slot_of(16), lm.slot_of(17))

    eviction = CacheEviction(lm).maybe_evict(rows, lm.slot_of(19), unanswered=1, keep_rows=rows)

    assert eviction is not None and eviction.keyframes_evicted == 15 and eviction.keyframes_kept == 5
    assert cached_ids(lm) == [15, 16, 17, 18, 19]  # the window and a 2-keyframe margin along covisibility
    assert lm.n_keyframes == 20 and lm.n_cached_keyframes == 5 and lm.n_slots == 5
    for kf_id in range(15, 20):  # kept keyframes observe the same points, at the same positions
        slot = lm.slot_of(kf_id)
        assert lm.keyframe(slot).id == kf_id
        ids = lm.point_ids[lm.keyframe_point_rows(slot)]
        assert np.array_equal(ids, before[kf_id])
        assert np.array_equal(lm.p_world[lm.rows_of_ids(ids)], np.stack([p_before[i] for i in ids.tolist()]))
    for kf_id in range(0, 15):
        assert lm.slot_of(kf_id) == -1
    # Points: exactly those the kept keyframes observe; the id index agrees with the rows.
    expected = np.unique(np.concatenate([before[k] for k in range(15, 20)]))
    assert np.array_equal(np.sort(lm.point_ids), expected)
    assert np.array_equal(lm.rows_of_ids(lm.point_ids), np.arange(lm.n_points))
    assert (lm.rows_of_ids(keyframes[3].new_point_ids) == -1).all()
    # Remaps: old rows and slots land on the same ids.
    kept_rows = np.flatnonzero(eviction.row_map >= 0)
    assert np.array_equal(lm.point_ids[eviction.row_map[kept_rows]], np.array(list(p_before))[kept_rows])
    assert eviction.slot_map.tolist() == [-1] * 15 + [0, 1, 2, 3, 4]
    # Covisibility and the spanning tree among kept keyframes are unchanged; 15 lost its parent (14).
    assert lm.covisibility_weight(lm.slot_of(16), lm.slot_of(17)) == weight == SHARED
    assert lm.parent(lm.slot_of(15)) == -1 and lm.parent(lm.slot_of(16)) == lm.slot_of(15)
    assert lm.best_covisible(lm.slot_of(15), 10) == [lm.slot_of(16)]
    # The window of the same frame is the same keyframes.
    new_rows = eviction.row_map[rows]
    assert sorted(lm.keyframe(s).id for s in local_window(lm, new_rows).keyframe_slots.tolist()) == [17, 18, 19]


def test_unanswered_keyframes_their_parents_and_the_reference_stay() -> None:
    lm, keyframes = corridor(20, CONFIG)
    rows = frame_rows_seeing(lm, keyframes[5])  # a frame back at keyframe 5
    CacheEviction(lm).maybe_evict(rows, reference_slot=lm.slot_of(0), unanswered=2)
    # Window 3..7 (voted 4, 5, 6), margin 2 and 8; the two newest (not answered by the backend)
    # with their parents; the reference.
    assert cached_ids(lm) == [0, 2, 3, 4, 5, 6, 7, 8, 17, 18, 19]
    assert lm.parent(lm.slot_of(19)) == lm.slot_of(18) and lm.parent(lm.slot_of(18)) == lm.slot_of(17)


def test_eviction_is_amortised_and_can_be_switched_off() -> None:
    # Window (3) and margin (4) hold more than the limit: passes run every 5 keyframes, not every one.
    config = LocalMapConfig(cache_max_keyframes=6, cache_margin_keyframes=4, cache_min_keyframes_between_evictions=5)
    lm = LocalMap(config)
    eviction = CacheEviction(lm)
    kf = corridor_keyframe(lm, np.zeros(0, dtype=np.int64), NEW, 0.0)
    sizes, passes = [], []
    for k in range(1, 40):
        kf = corridor_keyframe(lm, kf.new_point_ids[:SHARED], NEW, float(k))
        done = eviction.maybe_evict(frame_rows_seeing(lm, kf), lm.slot_of(kf.id), unanswered=1)
        passes.append(done is not None)
        sizes.append(lm.n_cached_keyframes)
    assert passes.index(True) == 5  # keyframe 6: the cache holds 7 > 6
    assert max(sizes) == 11 and {sizes[i] for i in np.flatnonzero(passes)} == {7}
    gaps = np.diff(np.flatnonzero(passes))
    assert len(gaps) >= 5 and (gaps == 5).all()
    off = LocalMap(LocalMapConfig(evict=False, cache_max_keyframes=1))
    kfs = [corridor_keyframe(off, np.zeros(0, dtype=np.int64), NEW, 0.0) for _ in range(3)]
    assert CacheEviction(off).maybe_evict(frame_rows_seeing(off, kfs[-1]), 2, 1) is None
    assert off.n_cached_keyframes == 3


def test_a_forced_pass_runs_when_no_insertion_paced_one() -> None:
    """Localisation mode fills the cache with restored keyframes only: a forced pass evicts although
    too few keyframes were inserted to pace one; with eviction off, nothing is evicted."""
    lm, keyframes = corridor(20, dataclasses.replace(CONFIG, cache_min_keyframes_between_evictions=50))
    eviction = CacheEviction(lm)
    rows = frame_rows_seeing(lm, keyframes[-1])
    assert not eviction.due() and eviction.maybe_evict(rows, lm.slot_of(19), unanswered=0) is None
    forced = eviction.maybe_evict(rows, lm.slot_of(19), unanswered=0, force=True)
    assert forced is not None and cached_ids(lm) == [15, 16, 17, 18, 19]
    off, kfs = corridor(20, dataclasses.replace(CONFIG, evict=False))
    assert CacheEviction(off).maybe_evict(frame_rows_seeing(off, kfs[-1]), off.slot_of(19), 0, force=True) is None


def test_map_updates_naming_evicted_keyframes_and_points() -> None:
    lm, keyframes = corridor(20, CONFIG)
    rows = frame_rows_seeing(lm, keyframes[-1])
    CacheEviction(lm).maybe_evict(rows, lm.slot_of(19), unanswered=1)
    assert cached_ids(lm) == [15, 16, 17, 18, 19]
    n_points = lm.n_points
    evicted_point = int(keyframes[3].new_point_ids[-1])  # only keyframe 3 saw it
    refilled_point = int(keyframes[2].new_point_ids[-1])  # keyframe 16 gets associated with it again
    backend_point = BACKEND_POINT_ID_BASE + 7
    kf16 = lm.keyframe(lm.slot_of(16))
    associations = kf16.map_point_ids.copy()
    associations[-1] = refilled_point
    shift = make_T(np.eye(3), np.array([0.0, 0.0, 0.5]))
    points = np.array([evicted_point, refilled_point, backend_point], dtype=np.int64)
    update = MapUpdate(
        keyframe_id=18,  # answers keyframe 18: 19 is not mapped yet and follows its parent's correction
        stamp_ns=0,
        keyframes=(
            KeyframeCorrection(4, np.eye(4), np.full(NEW + SHARED, -1, dtype=np.int64)),  # evicted: ignored
            KeyframeCorrection(16, kf16.T_world_cam, associations),
            KeyframeCorrection(18, shift @ lm.keyframe(lm.slot_of(18)).T_world_cam, lm.keyframe(lm.slot_of(18)).map_point_ids),
        ),
        point_ids=points,
        p_world=np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]),
        descriptors=np.zeros((3, 32), dtype=np.uint8),
        normals=np.tile([0.0, 0.0, 1.0], (3, 1)),
        min_distance_m=np.ones(3),
        max_distance_m=np.full(3, 10.0),
        removed_point_ids=np.asarray(keyframes[5].new_point_ids[:3]),  # evicted: nothing to do
        removed_keyframe_ids=np.array([6], dtype=np.int64),  # evicted: nothing to do
    )
    x19 = lm.keyframe(lm.slot_of(19)).T_world_cam.copy()
    apply_map_update(lm, update)

    assert cached_ids(lm) == [15, 16, 17, 18, 19] and lm.slot_of(4) == -1
    assert np.allclose(lm.keyframe(lm.slot_of(19)).T_world_cam, shift @ x19)  # carried with its parent 18
    # The point a held keyframe observes again comes back; those no held keyframe observes stay out.
    assert lm.rows_of_ids(points).tolist() == [-1, n_points, -1]
    assert lm.p_world[n_points].tolist() == [4.0, 5.0, 6.0] and lm.valid[n_points]
    observed = lm.point_ids[lm.keyframe_point_rows(lm.slot_of(16))].tolist()
    assert refilled_point in observed and evicted_point not in observed
    assert np.array_equal(lm.rows_of_ids(lm.point_ids), np.arange(lm.n_points))
    # A pass keeps the re-filled point; the point keyframe 16 no longer observes goes.
    lost = int(kf16.map_point_ids[-1])
    lm.retain(lm.cached_slots())
    assert lm.rows_of_ids(np.array([refilled_point, lost])).tolist()[1] == -1
    assert lm.rows_of_ids(np.array([refilled_point]))[0] >= 0


def test_culled_points_of_kept_keyframes_keep_their_rows_and_statistics() -> None:
    lm, keyframes = corridor(20, CONFIG)
    culled = keyframes[19].new_point_ids[:5]
    lm.remove_points(culled)
    lm.increase_visible(lm.rows_of_ids(keyframes[19].new_point_ids))
    visible = dict(zip(lm.point_ids.tolist(), lm.n_visible.tolist()))
    CacheEviction(lm).maybe_evict(frame_rows_seeing(lm, keyframes[-1]), lm.slot_of(19), unanswered=1)
    rows = lm.rows_of_ids(culled)
    assert (rows >= 0).all() and not lm.valid[rows].any()  # a later update may list them again
    assert all(lm.n_visible[r] == visible[i] for r, i in zip(lm.rows_of_ids(lm.point_ids), lm.point_ids.tolist()))


def test_invalid_cache_sizes_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="cache_max_keyframes=0"):
        LocalMapConfig(cache_max_keyframes=0)
    with pytest.raises(ConfigError, match="cache_margin_keyframes=-1"):
        LocalMapConfig(cache_margin_keyframes=-1)


def test_keyframes_to_keep_takes_the_margin_ring_by_ring() -> None:
    lm, keyframes = corridor(20, CONFIG)
    rows = frame_rows_seeing(lm, keyframes[10])  # voted 9, 10, 11; then 8 and 12, their neighbours
    assert keyframes_to_keep(lm, rows, [], 0).tolist() == [8, 9, 10, 11, 12]
    assert keyframes_to_keep(lm, rows, [], 2).tolist() == [7, 8, 9, 10, 11, 12, 13]
    assert keyframes_to_keep(lm, rows, [], 4).tolist() == [6, 7, 8, 9, 10, 11, 12, 13, 14]
    assert keyframes_to_keep(lm, rows, [0, -1], 0).tolist() == [0, 8, 9, 10, 11, 12]
