"""Local mapping on synthetic keyframe sequences: a consistent map, and the updates the frontend needs."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.backend.local_ba import BAProblem, BAResult, LocalBAConfig
from zenslam.backend.local_mapping import (
    TIMING_STEPS,
    BAWindowConfig,
    LocalMapper,
    bundle_adjuster,
    new_backend_map,
    LocalMappingConfig,
    apply_ba_result,
    local_ba_window,
)
from zenslam.backend.map import MapError
from zenslam.camera import PinholeCalibration
from zenslam.errors import ConfigError
from zenslam.geometry import invert_T, make_T, transform_points
from zenslam.map_rules_config import MapRulesConfig
from zenslam.schemas.codec import KeyframeMessage, encode_map_update
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE, MapUpdate
from zenslam.config import from_mapping

CAL = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)


class StubAdjuster:
    """Returns the window unchanged; optionally flags the given observation rows as outliers."""

    def __init__(self, outliers: tuple[int, ...] = ()) -> None:
        self.outliers = outliers
        self.problems: list[BAProblem] = []

    def optimize(self, problem: BAProblem) -> BAResult:
        self.problems.append(problem)
        inlier = np.ones(len(problem.obs_keyframe), dtype=bool)
        inlier[list(self.outliers)] = False
        return BAResult(problem.T_world_cam.copy(), problem.p_world.copy(), inlier, np.zeros(0, np.int64), {})


class SyntheticFrontend:
    """Keyframe messages from known geometry, with a minimal frontend that applies map updates.

    Camera moving along +x looking along +z; each visible point is a keypoint (exact projection
    plus ``noise_px``) with the point's descriptor and 3 flipped bits. Known points are associated;
    of the unknown ones, half get a new frontend point (true position), the rest are left for the
    backend to triangulate; ``duplicate_rate`` of known points get a fresh id (a duplicate), and
    ``clutter`` extra keypoints per keyframe have random descriptors, half of them a new point at a
    wrong depth (spurious, never seen again).
    """

    def __init__(self, sensor="stereo", n_points=300, step=0.15, noise_px=0.0, duplicate_rate=0.05, clutter=6, seed=0):
        self.rng = rng = np.random.default_rng(seed)
        self.p = np.column_stack([rng.uniform(-3, 5, n_points), rng.uniform(-1.5, 1.5, n_points), rng.uniform(2, 8, n_points)])
        self.desc = rng.integers(0, 256, (n_points, 32), dtype=np.uint8)
        self.level = rng.integers(0, 2, n_points)
        self.sensor, self.step, self.noise, self.dup, self.clutter = sensor, step, noise_px, duplicate_rate, clutter
        self.id_of: dict[int, int] = {}  # true point index -> the id the frontend knows it by
        self.truth: dict[int, np.ndarray] = {}  # keyframe id -> true point index per keypoint (-1 clutter)
        self.spurious: dict[int, int] = {}  # spurious point id -> keyframe that created it
        self.next_id = 0
        self.k = 0

    def pose(self, k: int) -> np.ndarray:
        return make_T(np.eye(3), [k * self.step, 0.0, 0.0])

    def _new_id(self) -> int:
        self.next_id += 1
        return self.next_id - 1

    def next_message(self) -> KeyframeMessage:
        rng, k, T = self.rng, self.k, self.pose(self.k)
        p_cam = transform_points(invert_T(T), self.p)
        z = p_cam[:, 2]
        px = CAL.fx * p_cam[:, :2] / np.maximum(z, 1e-9)[:, None] + [CAL.cx, CAL.cy]
        inside = (z > 0.5) & (px[:, 0] >= 0) & (px[:, 0] < 640) & (px[:, 1] >= 0) & (px[:, 1] < 480)
        vis = rng.permutation(np.flatnonzero(inside))
        n = len(vis) + self.clutter
        kp = np.vstack([px[vis], rng.uniform([0, 0], [640, 480], (self.clutter, 2))]) + rng.normal(0, self.noise, (n, 2))
        depth = np.r_[z[vis], rng.uniform(2, 8, self.clutter)]
        desc = np.vstack([self.desc[vis], rng.integers(0, 256, (self.clutter, 32), dtype=np.uint8)])
        for _ in range(3):
            desc[np.arange(n), rng.integers(0, 32, n)] ^= np.uint8(1 << int(rng.integers(0, 8)))
        ids, new_ids, new_p = np.full(n, -1, np.int64), [], []
        for j, t in enumerate(vis.tolist()):
            if t in self.id_of and rng.random() >= self.dup:
                ids[j] = self.id_of[t]
            elif t in self.id_of or rng.random() < 0.5:
                ids[j] = self._new_id()
                new_ids.append(ids[j])
                new_p.append(self.p[t])
                self.id_of.setdefault(t, int(ids[j]))
        stereo = self.sensor != "mono"
        for j in range(len(vis), n, 2):
            if stereo:  # spurious stereo point: a clutter keypoint with a made-up depth
                ids[j] = self._new_id()
                new_ids.append(ids[j])
                new_p.append(transform_points(T, np.array([[*(kp[j] - [CAL.cx, CAL.cy]) * depth[j] / CAL.fx, depth[j]]]))[0])
                self.spurious[int(ids[j])] = k
        self.truth[k] = np.r_[vis, np.full(self.clutter, -1)]
        self.k += 1
        return KeyframeMessage(
            id=k, stamp_ns=k * 100_000_000, frame_index=k, T_world_cam=T, calibration=CAL, sensor=self.sensor,
            keypoints_px=kp.astype(np.float32), levels=np.r_[self.level[vis], np.zeros(self.clutter, int)].astype(np.int16),
            angles_deg=np.zeros(n, np.float32), right_u=(kp[:, 0] - CAL.bf / depth if stereo else np.full(n, -1.0)).astype(np.float32),
            depth_m=(depth if stereo else np.full(n, -1.0)).astype(np.float32), descriptors=desc, map_point_ids=ids,
            scale_factors=1.2 ** np.arange(8), new_point_ids=np.asarray(new_ids, np.int64),
            new_points_world=np.asarray(new_p, float).reshape(-1, 3),
        )  # fmt: skip

    def apply(self, update: MapUpdate) -> None:
        """What the frontend keeps: removed ids forgotten, the latest keyframe's associations learnt."""
        removed = set(update.removed_point_ids.tolist())
        self.id_of = {t: p for t, p in self.id_of.items() if p not in removed}
        for correction in update.keyframes:
            if correction.id == self.k - 1:
                for j, point_id in enumerate(correction.map_point_ids.tolist()):
                    t = int(self.truth[correction.id][j])
                    if point_id >= 0 and t >= 0:
                        self.id_of[t] = point_id


def run(frontend: SyntheticFrontend, mapper: LocalMapper, n_keyframes: int) -> list[MapUpdate]:
    updates = []
    for _ in range(n_keyframes):
        updates.append(mapper.process(frontend.next_message()))
        frontend.apply(updates[-1])
        assert mapper.map.check_consistency() == []
    return updates


def test_config_sections_and_threshold_range() -> None:
    config = from_mapping(LocalMappingConfig, {"map_rules": {"min_covisibility_weight": 20}, "fusion": {"second_neighbours": 3}})
    assert config.map_rules.min_covisibility_weight == 20 and config.fusion.second_neighbours == 3
    with pytest.raises(ConfigError, match="15..30"):
        MapRulesConfig(min_covisibility_weight=10)
    with pytest.raises(ConfigError, match="unknown key"):
        from_mapping(LocalMappingConfig, {"triangulation": {"nn": 3}})


def test_stereo_sequence_keeps_the_map_consistent_and_accurate() -> None:
    frontend, mapper = SyntheticFrontend(), LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
    updates = run(frontend, mapper, 14)
    totals, bmap = mapper.totals, mapper.map
    assert totals["points_created"] > 0 and totals["points_fused"] > 0 and totals["keyframes_culled"] > 0
    assert set(mapper.last_timings_ms) == set(TIMING_STEPS)
    # spurious points born at least 3 keyframes ago were culled as recent points
    old_spurious = [p for p, k in frontend.spurious.items() if k <= frontend.k - 4]
    assert old_spurious and not any(p in bmap.points for p in old_spurious)
    # every point's observations are of one true point, at its true position (noise-free input)
    errors = []
    for pt in bmap.points.values():
        truths = {int(frontend.truth[k][i]) for k, i in pt.observations.items()}
        if pt.id in frontend.spurious:
            continue
        assert len(truths) == 1 and -1 not in truths, f"point {pt.id} mixes true points {truths}"
        errors.append(np.linalg.norm(pt.p_world - frontend.p[truths.pop()]))
    assert max(errors) < 1e-3  # metres
    assert any(p >= BACKEND_POINT_ID_BASE for p in bmap.points)
    # the last update carries the complete associations of the keyframes it lists
    for correction in updates[-1].keyframes:
        assert np.array_equal(correction.map_point_ids, bmap.keyframes[correction.id].map_point_ids)
        np.testing.assert_array_equal(correction.T_world_cam, bmap.keyframes[correction.id].T_world_cam)
    assert updates[-1].keyframe_id == 13 and 13 in [c.id for c in updates[-1].keyframes]


def test_updates_describe_points_and_removals_consistently() -> None:
    frontend, mapper = SyntheticFrontend(seed=1), LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
    known: set[int] = set()
    for _ in range(8):
        update = mapper.process(frontend.next_message())
        frontend.apply(update)
        assert not set(update.removed_point_ids.tolist()) & set(mapper.map.points)
        assert not set(update.removed_keyframe_ids.tolist()) & set(mapper.map.keyframes)
        known |= set(update.point_ids.tolist())
        known -= set(update.removed_point_ids.tolist())
        for correction in update.keyframes:  # every point a listed keyframe names is known to the frontend
            ids = correction.map_point_ids[correction.map_point_ids >= 0]
            assert set(ids.tolist()) <= known
        for i, point_id in enumerate(update.point_ids.tolist()):
            pt = mapper.map.points[point_id]
            assert np.array_equal(update.descriptors[i], pt.descriptor)
            assert 0 < update.min_distance_m[i] < update.max_distance_m[i]
            assert 0.5 < np.linalg.norm(update.normals[i]) <= 1.0 + 1e-12


def test_monocular_sequence_keeps_the_map_consistent() -> None:
    frontend = SyntheticFrontend(sensor="mono", clutter=0, seed=2)
    mapper = LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
    run(frontend, mapper, 10)
    assert mapper.totals["points_created"] > 0


def test_same_keyframes_give_the_same_update_bytes() -> None:
    outputs = []
    for _ in range(2):
        frontend, mapper = SyntheticFrontend(seed=7), LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
        outputs.append([encode_map_update(update) for update in run(frontend, mapper, 6)])
    assert outputs[0] == outputs[1]


def test_stale_and_repeated_associations_are_dropped() -> None:
    frontend, mapper = SyntheticFrontend(seed=3), LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
    run(frontend, mapper, 2)
    msg = frontend.next_message()
    ids = msg.map_point_ids.copy()
    known = np.flatnonzero((ids >= 0) & ~np.isin(ids, msg.new_point_ids))
    ids[known[0]] = 10**9  # never existed
    ids[known[2]] = ids[known[1]]  # the same point twice
    msg = KeyframeMessage(**{**msg.__dict__, "map_point_ids": ids})
    update = mapper.process(msg)
    assert mapper.last_stats.associations_dropped == 2
    correction = next(c for c in update.keyframes if c.id == msg.id)
    assert correction.map_point_ids[known[0]] != 10**9
    with pytest.raises(MapError, match="already in the backend map"):
        mapper.process(msg)


def test_associations_far_from_the_backends_points_are_dropped_at_insertion() -> None:
    """The frontend matched against positions that may lag the backend's: an association whose
    point reprojects far off (or behind the camera) in the new keyframe is not inserted."""
    frontend, mapper = SyntheticFrontend(seed=4), LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
    run(frontend, mapper, 2)
    msg = frontend.next_message()
    known = np.flatnonzero((msg.map_point_ids >= 0) & ~np.isin(msg.map_point_ids, msg.new_point_ids))
    moved, behind = int(msg.map_point_ids[known[0]]), int(msg.map_point_ids[known[1]])
    mapper.map.points[moved].p_world = mapper.map.points[moved].p_world + [0.5, 0.0, 0.0]  # ~35+ px at 2-8 m
    mapper.map.points[behind].p_world = np.array([msg.T_world_cam[0, 3], 0.0, -5.0])
    slightly = int(msg.map_point_ids[known[2]])
    mapper.map.points[slightly].p_world = mapper.map.points[slightly].p_world + [0.005, 0.0, 0.0]  # < 1 px: kept
    update = mapper.process(msg)
    assert mapper.last_stats.associations_dropped == 2
    correction = next(c for c in update.keyframes if c.id == msg.id)
    assert correction.map_point_ids[known[0]] == -1 and correction.map_point_ids[known[1]] == -1
    assert correction.map_point_ids[known[2]] == slightly
    assert mapper.map.check_consistency() == []


def test_ba_window_fixes_the_gauge_and_the_outer_keyframes() -> None:
    frontend, mapper = SyntheticFrontend(seed=4), LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
    run(frontend, mapper, 6)
    bmap, current = mapper.map, max(mapper.map.keyframes)
    problem, obs_points, obs_kfs = local_ba_window(bmap, current, BAWindowConfig(max_local_keyframes=3, max_fixed_keyframes=1))
    ids = problem.keyframe_ids.tolist()
    assert ids[:3] == [current, *bmap.covisibility.connected(current)[:2]]
    assert problem.fixed.tolist()[:3] == [False, False, bmap.first_keyframe_id in ids[1:3]]
    assert len(ids) <= 4 and problem.fixed[3:].all()
    local_points = {p for k in ids[:3] for p in bmap.keyframe_point_ids(k).tolist()}
    assert set(problem.point_ids.tolist()) == local_points
    for o in range(len(obs_points)):
        kf = bmap.keyframes[int(obs_kfs[o])]
        keypoint = bmap.points[int(obs_points[o])].observations[kf.id]
        np.testing.assert_array_equal(problem.obs_px[o], kf.keypoints_px[keypoint])
        assert problem.obs_inv_sigma2[o] == pytest.approx(1.2 ** (-2 * kf.levels[keypoint]))
        assert np.isnan(problem.obs_right_u[o]) == (kf.right_u[keypoint] < 0)
        far = kf.right_u[keypoint] >= 0 and kf.depth_m[keypoint] > BAWindowConfig().stereo_max_depth_baselines * CAL.baseline_m
        assert problem.obs_right_sigma_scale[o] == (BAWindowConfig().far_right_sigma_scale if far else 1.0)


def test_ba_window_weakens_or_drops_far_disparities() -> None:
    frontend, mapper = SyntheticFrontend(seed=4), LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
    run(frontend, mapper, 4)
    bmap, current = mapper.map, max(mapper.map.keyframes)
    all_stereo, _, _ = local_ba_window(bmap, current, BAWindowConfig(stereo_max_depth_baselines=0.0))
    assert np.all(all_stereo.obs_right_sigma_scale == 1.0)
    limit = 40.0  # baselines: the synthetic scene's depths (2-8 m, baseline 0.1 m) straddle it
    config = BAWindowConfig(stereo_max_depth_baselines=limit, far_right_sigma_scale=5.0)
    weak, _, _ = local_ba_window(bmap, current, config)
    config = BAWindowConfig(stereo_max_depth_baselines=limit, far_right_sigma_scale=float("inf"))
    near_only, obs_points, obs_kfs = local_ba_window(bmap, current, config)
    depth = np.array([bmap.keyframes[int(k)].depth_m[bmap.points[int(p)].observations[int(k)]] for p, k in zip(obs_points, obs_kfs)])
    stereo_all = np.isfinite(all_stereo.obs_right_u)
    assert np.any(stereo_all & (depth > limit * CAL.baseline_m)) and np.any(stereo_all & (depth <= limit * CAL.baseline_m))
    np.testing.assert_array_equal(np.isfinite(near_only.obs_right_u), stereo_all & (depth <= limit * CAL.baseline_m))
    np.testing.assert_array_equal(near_only.obs_px, all_stereo.obs_px)
    np.testing.assert_array_equal(weak.obs_right_sigma_scale, np.where(stereo_all & (depth > limit * CAL.baseline_m), 5.0, 1.0))


def test_ba_window_gives_rgbd_disparities_the_depth_sensors_sigma_and_no_far_rule() -> None:
    frontend, mapper = SyntheticFrontend(sensor="rgbd", seed=4), LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
    run(frontend, mapper, 4)
    bmap, current = mapper.map, max(mapper.map.keyframes)
    config = BAWindowConfig(stereo_max_depth_baselines=40.0)  # the scene's 2-8 m depths straddle 4 m
    problem, _, _ = local_ba_window(bmap, current, config)
    rgbd = np.isfinite(problem.obs_right_u)
    assert rgbd.any()
    np.testing.assert_allclose(problem.obs_disparity_sigma, np.where(rgbd, CAL.bf * config.rgbd_depth_sigma_at_1m, 0.0))
    assert np.all(problem.obs_right_sigma_scale == 1.0)
    orb_slam, _, _ = local_ba_window(bmap, current, BAWindowConfig(stereo_max_depth_baselines=40.0, rgbd_depth_sigma_at_1m=0.0))
    assert np.all(orb_slam.obs_disparity_sigma == 0.0) and np.any(orb_slam.obs_right_sigma_scale > 1.0)
    stereo_frontend, stereo_mapper = SyntheticFrontend(seed=4), LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
    run(stereo_frontend, stereo_mapper, 4)
    stereo, _, _ = local_ba_window(stereo_mapper.map, max(stereo_mapper.map.keyframes), config)
    assert np.all(stereo.obs_disparity_sigma == 0.0)


def test_ba_outliers_leave_both_sides_and_weak_points_go() -> None:
    frontend, mapper = SyntheticFrontend(seed=5), LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), StubAdjuster())
    run(frontend, mapper, 4)
    bmap = mapper.map
    problem, obs_points, obs_kfs = local_ba_window(bmap, 3, BAWindowConfig())
    counts = {p: len(bmap.points[p].observations) for p in problem.point_ids.tolist()}
    two = next(o for o in range(len(obs_points)) if counts[int(obs_points[o])] == 2)
    many = next(o for o in range(len(obs_points)) if counts[int(obs_points[o])] >= 3)
    result = StubAdjuster(outliers=(two, many)).optimize(problem)
    stats = apply_ba_result(bmap, problem, result, obs_points, obs_kfs, min_keyframes_per_point=2)
    assert stats == {"ba_outliers": 2, "points_removed_after_ba": 1}
    assert int(obs_points[two]) not in bmap.points  # left with one observer
    assert int(obs_kfs[many]) not in bmap.points[int(obs_points[many])].observations
    assert bmap.check_consistency() == []


def test_with_the_real_bundle_adjuster_poses_stay_on_the_truth() -> None:
    frontend = SyntheticFrontend(noise_px=0.5, n_points=200, seed=6)
    mapper = LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), bundle_adjuster(LocalBAConfig()))
    run(frontend, mapper, 6)
    assert mapper.last_ba_stats  # BA ran
    for kf_id, kf in mapper.map.keyframes.items():
        assert np.linalg.norm(kf.T_world_cam[:3, 3] - frontend.pose(kf_id)[:3, 3]) < 0.02  # metres


def test_a_backlog_defers_fusion_ba_and_keyframe_culling_to_the_last_queued_keyframe() -> None:
    frontend, adjuster = SyntheticFrontend(seed=6), StubAdjuster()
    mapper = LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), adjuster)
    run(frontend, mapper, 3)
    n_ba = len(adjuster.problems)
    message = frontend.next_message()
    update = mapper.process(message, queued=2)
    frontend.apply(update)
    assert len(adjuster.problems) == n_ba and mapper.last_stats.deferred == 1
    assert mapper.last_stats.fusion_matches == 0 and mapper.last_stats.keyframes_culled == 0
    assert any(c.id == message.id for c in update.keyframes)  # inserted, its associations published
    assert mapper.map.check_consistency() == []
    frontend.apply(mapper.process(frontend.next_message(), queued=0))
    assert len(adjuster.problems) == n_ba + 1 and mapper.last_stats.deferred == 0


def test_local_ba_runs_at_most_once_per_min_interval_of_keyframe_stamps() -> None:
    """Keyframes 0.1 s apart with ``ba_window.min_interval_s`` 0.25: BA on every third keyframe from
    the first window on, the ones between mapped without one and flagged; 0 runs it on every one."""
    config = from_mapping(LocalMappingConfig, {"ba_window": {"min_interval_s": 0.25}})
    frontend, adjuster = SyntheticFrontend(seed=7), StubAdjuster()
    mapper = LocalMapper(new_backend_map(config), config, adjuster)
    with_ba, waited = [], []
    for k in range(12):
        n_ba = len(adjuster.problems)
        frontend.apply(mapper.process(frontend.next_message()))
        assert mapper.map.check_consistency() == []
        if len(adjuster.problems) > n_ba:
            with_ba.append(k)
        waited.append(mapper.last_stats.ba_waited)
    assert with_ba == [2, 5, 8, 11]  # keyframes 0 and 1: too few keyframes for a window (min_keyframes 3)
    assert [k for k, w in enumerate(waited) if w] == [3, 4, 6, 7, 9, 10]

    every = StubAdjuster()
    mapper = LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), every)
    run(SyntheticFrontend(seed=7), mapper, 12)
    assert len(every.problems) == 10 and mapper.totals["ba_waited"] == 0


def test_local_ba_min_interval_is_a_finite_time() -> None:
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="min_interval_s"):
            BAWindowConfig(min_interval_s=bad)
