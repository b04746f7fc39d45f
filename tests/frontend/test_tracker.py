"""Tracking on a short synthetic stereo sequence made of keypoints with known 3D truth (no rendering)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.frontend.frame import Frame, frame_pose_information, optimize_frame_pose
from zenslam.frontend.keyframe import unproject_keypoints
from zenslam.frontend.orb_extractor import Features
from zenslam.frontend.pose_filter import PoseEstimate, fuse, predict
from zenslam.frontend.config import FrontendConfig
from zenslam.frontend.keyframe_decision import KeyframeDecisionConfig
from zenslam.frontend.pipeline import FrontendPipeline
from zenslam.frontend.tracker import TrackingConfig
from zenslam.frontend.visual_odometry import LastFrameSearch, last_frame_points, optimise_with_odometry, track_last_frame
from zenslam.geometry import invert_T, make_T, se3_exp, so3_exp, so3_log
from zenslam.pose_optimizer import PoseOptimizerConfig

CAL = PinholeCalibration(fx=450.0, fy=450.0, cx=320.0, cy=240.0, width=640, height=480, baseline_m=0.12)
SCALES = 1.2 ** np.arange(8)
# The tracker's motion-model search (TrackingConfig's defaults).
SEARCH = LastFrameSearch(radius_px=15.0, wide_factor=2.0, min_matches=20, max_distance=100, check_orientation=True)


class PointWorld:
    """Random 3D points with fixed descriptors and physical sizes, seen along a smooth path."""

    def __init__(self, seed: int = 0, n_points: int = 6000) -> None:
        rng = np.random.default_rng(seed)
        self.rng = rng
        self.p_world = np.column_stack(
            [rng.uniform(-12, 12, n_points), rng.uniform(-4, 4, n_points), rng.uniform(2, 30, n_points)]
        )
        self.descriptors = rng.integers(0, 256, (n_points, 32), dtype=np.uint8)
        # The pyramid level a point is detected at follows its apparent size: c / distance.
        self.size_constant = rng.uniform(3.0, 3.0 * 1.2**4, n_points)

    @staticmethod
    def pose(k: int) -> np.ndarray:
        """T_world_cam of frame k: forward 20 cm per frame with a steady yaw and a little sway."""
        rotation = so3_exp(np.array([0.0, 0.012 * k, 0.002 * np.sin(0.3 * k)]))
        return make_T(rotation, np.array([0.05 * np.sin(0.2 * k), 0.0, 0.2 * k]))

    def frame(self, k: int, keep_fraction: float = 0.75, corrupt: bool = False) -> Frame:
        """The keypoints of frame k: a random ``keep_fraction`` of the visible points, plus distractors."""
        rng = self.rng
        T_cam_world = invert_T(self.pose(k))
        p_cam = self.p_world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        z = p_cam[:, 2]
        safe_z = np.where(z > 0.1, z, 0.1)
        u = CAL.fx * p_cam[:, 0] / safe_z + CAL.cx
        v = CAL.fy * p_cam[:, 1] / safe_z + CAL.cy
        seen = (z > 0.5) & (u >= 5) & (u < CAL.width - 5) & (v >= 5) & (v < CAL.height - 5)
        seen &= rng.random(len(seen)) < keep_fraction
        idx = np.flatnonzero(seen)
        n_true = len(idx)
        px = np.column_stack([u[idx], v[idx]]) + rng.normal(0.0, 0.3, (n_true, 2))
        level = np.clip(np.floor(np.log(self.size_constant[idx] / z[idx]) / np.log(1.2)), 0, 7).astype(np.int16)
        desc = self.descriptors[idx].copy()
        flips = rng.integers(0, 256, (n_true, 4))
        for j in range(4):
            desc[np.arange(n_true), flips[:, j] // 8] ^= (1 << (flips[:, j] % 8)).astype(np.uint8)
        disparity = CAL.bf / z[idx] + rng.normal(0.0, 0.2, n_true)
        stereo = (disparity > 1.0) & (rng.random(n_true) < 0.7)
        n_fake = 150
        px = np.vstack([px, rng.uniform([0, 0], [CAL.width, CAL.height], (n_fake, 2))])
        level = np.concatenate([level, rng.integers(0, 8, n_fake).astype(np.int16)])
        desc = np.vstack([desc, rng.integers(0, 256, (n_fake, 32), dtype=np.uint8)])
        right_u = np.concatenate([np.where(stereo, px[:n_true, 0] - disparity, -1.0), np.full(n_fake, -1.0)])
        depth = np.concatenate([np.where(stereo, CAL.bf / np.maximum(disparity, 1e-6), -1.0), np.full(n_fake, -1.0)])
        if corrupt:
            desc = rng.integers(0, 256, desc.shape, dtype=np.uint8)
        features = Features(
            px=px.astype(np.float32),
            level=level,
            angle_deg=np.zeros(len(px), dtype=np.float32),
            response=np.ones(len(px), dtype=np.float32),
            descriptors=desc,
            scale_factors=SCALES,
            inv_level_sigma2=1.0 / SCALES**2,
        )
        return Frame(k, k * 100_000_000, CAL, features, right_u.astype(np.float32), depth.astype(np.float32))


def _pipeline(config: TrackingConfig) -> FrontendPipeline:
    """A pipeline tracking built frames with ``config`` and the tracker's default pose and keyframe settings."""
    return FrontendPipeline(FrontendConfig(tracking=config, pose=PoseOptimizerConfig(), keyframe=KeyframeDecisionConfig()), CAL, "stereo")


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    delta = invert_T(T_true) @ T_est
    return float(np.linalg.norm(delta[:3, 3])), float(np.degrees(np.linalg.norm(so3_log(delta[:3, :3]))))


@pytest.fixture(scope="module")
def tracked_sequence():
    world = PointWorld(seed=0)
    pipeline = _pipeline(TrackingConfig())
    results = [pipeline.track(world.frame(k)) for k in range(25)]
    return world, pipeline, results


def test_tracks_every_frame_accurately(tracked_sequence) -> None:
    world, _, results = tracked_sequence
    assert [r.state for r in results] == ["ok"] * len(results)
    T0 = world.pose(0)
    for k, r in enumerate(results):
        t_err, r_err = pose_errors(r.T_world_cam, invert_T(T0) @ world.pose(k))
        # Frame-to-map tracking without bundle adjustment drifts: allow 5 mm + 0.5 % of the 0.2 m/frame path.
        assert t_err < 0.005 + 0.005 * 0.2 * k, f"frame {k}: position error {t_err:.4f} m"
        assert r_err < 0.1, f"frame {k}: rotation error {r_err:.3f} deg"
    assert all(r.n_tracked >= 30 for r in results)


def test_keyframes_and_points(tracked_sequence) -> None:
    _, pipeline, results = tracked_sequence
    keyframes = [r.keyframe for r in results if r.keyframe is not None]
    assert results[0].keyframe is not None and len(keyframes) >= 2
    assert [kf.id for kf in keyframes] == list(range(len(keyframes)))
    all_new = np.concatenate([kf.new_point_ids for kf in keyframes])
    assert np.array_equal(all_new, np.arange(len(all_new)))  # frontend ids start at 0 and increase
    lm = pipeline.tracker.map
    for kf in keyframes:
        assert np.array_equal(kf.map_point_ids[kf.new_point_keypoints], kf.new_point_ids)
        assert np.all(kf.depth_m[kf.new_point_keypoints] > 0)
        rows = lm.rows_of_ids(kf.new_point_ids)
        # Points keep the position they were created at (no backend moved them).
        assert np.allclose(lm.p_world[rows], kf.new_points_world)
    later = keyframes[1]
    assert np.count_nonzero(later.map_point_ids >= 0) > len(later.new_point_ids)  # observes older points too
    assert all(set(r.timings_ms) >= {"motion_model_tracking", "local_map_tracking", "pose_optimization",
                                     "keyframe_decision"} for r in results)


def test_lost_frame_then_recovery_from_the_reference_keyframe() -> None:
    world = PointWorld(seed=1)
    pipeline = _pipeline(TrackingConfig())
    for k in range(6):
        assert pipeline.track(world.frame(k)).state == "ok"
    lost = pipeline.track(world.frame(6, corrupt=True))
    assert lost.state == "lost" and lost.T_world_cam is None
    assert lost.lost_reason == "too_few_matches_motion_model_and_reference"
    assert not pipeline.tracker.motion.has_velocity
    back = pipeline.track(world.frame(7))
    assert back.state == "ok"
    t_err, _ = pose_errors(back.T_world_cam, invert_T(world.pose(0)) @ world.pose(7))
    assert t_err < 0.02
    assert pipeline.tracker.lost_reasons == {"too_few_matches_motion_model_and_reference": 1}


def test_restarts_after_a_long_loss_and_waits_for_depth_to_initialise() -> None:
    world = PointWorld(seed=2)
    config = TrackingConfig(reinit_after_lost_frames=2)
    pipeline = _pipeline(config)
    empty = world.frame(0)
    no_depth = dataclasses.replace(empty, right_u=np.full_like(empty.right_u, -1), depth_m=np.full_like(empty.depth_m, -1))
    first = pipeline.track(no_depth)
    assert first.state == "initializing" and first.lost_reason == "no_depth_points_for_init"
    assert pipeline.track(world.frame(0)).state == "ok"
    assert pipeline.track(world.frame(1)).state == "ok"
    assert pipeline.track(world.frame(2, corrupt=True)).state == "lost"
    assert pipeline.track(world.frame(3, corrupt=True)).state == "lost"
    restart = pipeline.track(world.frame(4))
    assert restart.state == "initializing" and restart.keyframe is not None
    # Restarted at the last good pose (frame 1's), then tracks again from there.
    assert np.allclose(restart.T_world_cam, invert_T(world.pose(0)) @ world.pose(1), atol=0.01)
    assert pipeline.track(world.frame(5)).state == "ok"
    assert pipeline.tracker.n_reinitialisations == 1


def test_tracking_is_deterministic() -> None:
    def run() -> list[np.ndarray]:
        world = PointWorld(seed=3)
        pipeline = _pipeline(TrackingConfig())
        return [pipeline.track(world.frame(k)).T_world_cam for k in range(8)]

    assert all(np.array_equal(a, b) for a, b in zip(run(), run()))


def test_map_update_moves_the_map_and_tracking_follows() -> None:
    """A backend correction that moves the whole map rigidly: the next frame is tracked in the moved map."""
    from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate

    world = PointWorld(seed=4)
    pipeline = _pipeline(TrackingConfig())
    for k in range(6):
        assert pipeline.track(world.frame(k)).state == "ok"
    G = make_T(so3_exp(np.array([0.0, 0.3, 0.0])), np.array([1.0, -2.0, 0.5]))  # new world <- old world
    lm = pipeline.tracker.map
    rows = np.flatnonzero(lm.valid)
    keyframes = [lm.keyframe(s) for s in range(lm.n_keyframes)]
    update = MapUpdate(
        keyframe_id=keyframes[-1].id,
        stamp_ns=keyframes[-1].stamp_ns,
        keyframes=tuple(KeyframeCorrection(kf.id, G @ kf.T_world_cam, kf.map_point_ids) for kf in keyframes),
        point_ids=lm.point_ids[rows],
        p_world=lm.p_world[rows] @ G[:3, :3].T + G[:3, 3],
        descriptors=lm.descriptors[rows],
        normals=lm.normals[rows] @ G[:3, :3].T,
        min_distance_m=lm.min_distance_m[rows],
        max_distance_m=lm.max_distance_m[rows],
    )
    pipeline.map_sync.apply(update)
    result = pipeline.track(world.frame(6))
    assert result.state == "ok"
    t_err, r_err = pose_errors(result.T_world_cam, G @ invert_T(world.pose(0)) @ world.pose(6))
    assert t_err < 0.02 and r_err < 0.1


def test_skipped_frames_are_tracked_by_the_scaled_motion_model(monkeypatch) -> None:
    """Live mode skips frames: the motion model predicts across the gap (the reference-keyframe
    fallback is disabled here, so only the prediction can track the frame)."""
    world = PointWorld(seed=5)
    pipeline = _pipeline(TrackingConfig())
    for k in range(4):
        assert pipeline.track(world.frame(k)).state == "ok"
    monkeypatch.setattr(pipeline.tracker.reference_tracking, "track", lambda frame, *args: None)
    T0 = world.pose(0)
    for k in (9, 10, 14):  # gaps of 6, 1 and 4 frames (1.2 m and 4 degrees of yaw for 6)
        result = pipeline.track(world.frame(k))
        assert result.state == "ok", (k, result.lost_reason)
        t_err, r_err = pose_errors(result.T_world_cam, invert_T(T0) @ world.pose(k))
        assert t_err < 0.02 and r_err < 0.1, (k, t_err, r_err)
    # The velocity stays per frame: about 0.2 m forward (the truth's step), not 0.8 m.
    assert np.linalg.norm(pipeline.tracker.motion.velocity[:3, 3]) == pytest.approx(0.2, abs=0.02)


def test_a_small_map_cache_evicts_and_tracking_stays_accurate() -> None:
    """Past 4 cached keyframes the tracker evicts around its window; the slots and rows it holds
    (reference keyframe, last frame's matches) are remapped, so tracking goes on as accurately."""
    from zenslam.frontend.local_map import LocalMapConfig

    world = PointWorld(seed=0)
    cache = LocalMapConfig(cache_max_keyframes=4, cache_margin_keyframes=1, cache_min_keyframes_between_evictions=2)
    pipeline = _pipeline(TrackingConfig(local_map=cache))
    T0 = world.pose(0)
    for k in range(70):
        result = pipeline.track(world.frame(k))
        assert result.state == "ok", (k, result.lost_reason)
        t_err, r_err = pose_errors(result.T_world_cam, invert_T(T0) @ world.pose(k))
        # The bounds of test_tracks_every_frame_accurately; rotation drifts to ~0.4 deg by frame 70.
        assert t_err < 0.005 + 0.005 * 0.2 * k and r_err < 0.5, (k, t_err, r_err)
        reference = pipeline.tracker.map.keyframe(pipeline.tracker.map.slot_of(result.reference_keyframe_id))
        assert np.allclose(reference.T_cam_world @ result.T_world_cam, result.T_reference_cam)
    lm = pipeline.tracker.map
    assert pipeline.tracker.eviction.passes >= 3 and 2 * lm.n_cached_keyframes <= lm.n_keyframes
    assert np.array_equal(lm.rows_of_ids(lm.point_ids), np.arange(lm.n_points))


def _merged(a: Frame, b: Frame) -> Frame:
    """One frame with the keypoints of both (the points of two worlds seen at once)."""
    fa, fb = a.features, b.features
    features = Features(
        *(np.concatenate([getattr(fa, name), getattr(fb, name)]) for name in ("px", "level", "angle_deg", "response", "descriptors")),
        scale_factors=SCALES, inv_level_sigma2=1.0 / SCALES**2,
    )  # fmt: skip
    return Frame(a.index, a.stamp_ns, CAL, features, np.concatenate([a.right_u, b.right_u]), np.concatenate([a.depth_m, b.depth_m]))


def test_localization_makes_no_keyframe_and_goes_on_by_visual_odometry() -> None:
    """Localisation mode: after the first keyframe no keyframe is made; where the map's points fade out
    (the frames see another world's points) the pose goes on by visual odometry on the last frame's depths."""
    mapped, unmapped = PointWorld(seed=5), PointWorld(seed=6)
    pipeline = _pipeline(TrackingConfig(localization=True))
    results = [pipeline.track(mapped.frame(k)) for k in range(3)]
    for k in range(3, 16):
        results.append(pipeline.track(_merged(mapped.frame(k, keep_fraction=0.75 if k < 6 else 0.002), unmapped.frame(k))))
    assert [r.state for r in results] == ["ok"] * 16
    assert results[0].keyframe is not None and all(r.keyframe is None for r in results[1:])
    assert pipeline.tracker.map.n_keyframes == 1 and pipeline.tracker.n_vo_frames >= 5
    assert all(r.n_tracked < 10 for r in results[8:])  # few map matches: the frames are on visual odometry
    T0 = mapped.pose(0)
    for k, r in enumerate(results):
        t_err, r_err = pose_errors(r.T_world_cam, invert_T(T0) @ mapped.pose(k))
        assert t_err < 0.01 + 0.005 * 0.2 * k and r_err < 0.3, f"frame {k}: {t_err:.4f} m, {r_err:.3f} deg"


def test_visual_odometry_alone_follows_the_camera() -> None:
    """``track_last_frame`` with no map point: the last frame's depth points give the motion."""
    from zenslam.pose_optimizer import PoseOptimizerConfig
    from zenslam.frontend.visual_odometry import VisualOdometryConfig, last_frame_points, track_last_frame

    world = PointWorld(seed=7)
    last, current = world.frame(3), world.frame(4)
    T_cam_world_last = invert_T(world.pose(3))
    none = np.full(len(last.features), -1, dtype=np.int64)
    points = last_frame_points(last, none, T_cam_world_last, np.zeros((0, 3)), np.zeros((0, 32), np.uint8), np.zeros(0, bool), 4.0, 100)
    assert np.all(points.rows == -1) and len(points.keypoints) >= 100
    found = track_last_frame(current, last, points, T_cam_world_last, SEARCH, PoseOptimizerConfig())
    assert found is not None and found.n_map == 0 and found.n_total >= 20 and found.is_vo(VisualOdometryConfig())
    t_err, r_err = pose_errors(invert_T(found.T_cam_world), world.pose(4))
    assert t_err < 0.01 and r_err < 0.1


def test_the_last_frames_near_points_steady_a_pose_on_few_biased_map_points() -> None:
    """``optimise_with_odometry``: 25 map points all off by 10 cm pull a map-only pose with them; with the
    odometry's VO matches added the pose stays much nearer the truth."""
    from zenslam.pose_optimizer import PoseOptimizerConfig, optimize_pose
    from zenslam.frontend.visual_odometry import VisualOdometryConfig, last_frame_points, optimise_with_odometry, track_last_frame

    world = PointWorld(seed=8)
    last, current = world.frame(3), world.frame(4)
    T_cam_world_last, T_true = invert_T(world.pose(3)), invert_T(world.pose(4))
    none = np.full(len(last.features), -1, dtype=np.int64)
    points = last_frame_points(last, none, T_cam_world_last, np.zeros((0, 3)), np.zeros((0, 32), np.uint8), np.zeros(0, bool), 4.0, 100)
    odometry = track_last_frame(current, last, points, T_cam_world_last, SEARCH, PoseOptimizerConfig())
    assert odometry is not None and len(odometry.vo_keypoints) >= 50
    # Map matches: 25 other keypoints of the current frame with depth, their points shifted 10 cm along x.
    with_depth = np.flatnonzero(current.depth_m > 0)
    map_kps = with_depth[~np.isin(with_depth, odometry.vo_keypoints)][:25]
    from zenslam.frontend.keyframe import unproject_keypoints

    p_true = unproject_keypoints(current.features.px[map_kps], current.depth_m[map_kps], CAL, world.pose(4))
    p_biased = p_true + np.array([0.10, 0.0, 0.0])
    feats = current.features
    right = np.where(current.right_u[map_kps] >= 0, current.right_u[map_kps], np.nan).astype(float)
    alone = optimize_pose(
        T_cam_world_last, p_biased, feats.px[map_kps].astype(float), right, feats.inv_level_sigma2[feats.level[map_kps]], CAL,
        PoseOptimizerConfig(),
    ).T_cam_world  # fmt: skip
    joint, inliers = optimise_with_odometry(current, T_cam_world_last, map_kps, p_biased, odometry, PoseOptimizerConfig())
    error_alone, _ = pose_errors(invert_T(alone), invert_T(T_true))
    error_joint, _ = pose_errors(invert_T(joint), invert_T(T_true))
    assert error_alone > 0.08 and error_joint < 0.5 * error_alone and inliers.shape == (25,)


def _odometry_and_map(world: PointWorld, T_cam_world_last: np.ndarray, map_shift_m: float, n_map: int):
    """Frame 4 matched to frame 3's VO points (frame 3 placed at ``T_cam_world_last``) and ``n_map``
    of its other keypoints on map points shifted ``map_shift_m`` along x."""
    last, current = world.frame(3), world.frame(4)
    none = np.full(len(last.features), -1, dtype=np.int64)
    points = last_frame_points(last, none, T_cam_world_last, np.zeros((0, 3)), np.zeros((0, 32), np.uint8), np.zeros(0, bool), 4.0, 100)
    odometry = track_last_frame(current, last, points, T_cam_world_last, SEARCH, PoseOptimizerConfig())
    assert odometry is not None and len(odometry.vo_keypoints) >= 50
    with_depth = np.flatnonzero(current.depth_m > 0)
    map_kps = with_depth[~np.isin(with_depth, odometry.vo_keypoints)][:n_map]
    p_map = unproject_keypoints(current.features.px[map_kps], current.depth_m[map_kps], CAL, world.pose(4)) + np.array([map_shift_m, 0.0, 0.0])
    return current, odometry, map_kps, p_map


def _filtered(current, odometry, map_kps, p_map, source: PoseEstimate) -> np.ndarray:
    """The tracker's filter step: the map-only pose fused with the VO points' prediction from ``source``."""
    config = PoseOptimizerConfig()
    alone = optimize_frame_pose(current, odometry.T_cam_world, map_kps, p_map, config)
    inl = alone.inliers
    map_information = frame_pose_information(current, alone.T_cam_world, map_kps[inl], p_map[inl])
    vo = optimize_frame_pose(current, odometry.T_cam_world, odometry.vo_keypoints, odometry.vo_p_world, config)
    vo_information = frame_pose_information(current, vo.T_cam_world, odometry.vo_keypoints[vo.inliers], odometry.vo_p_world[vo.inliers])
    return fuse(alone.T_cam_world, map_information, predict(source, vo.T_cam_world, vo_information)).T_cam_world


def test_an_exact_last_frame_steadies_a_pose_on_few_biased_map_points() -> None:
    """As ORB-SLAM2's exact VO points do: 25 map points all off by 10 cm, a last frame known exactly."""
    world = PointWorld(seed=8)
    T_last = invert_T(world.pose(3))
    current, odometry, map_kps, p_map = _odometry_and_map(world, T_last, 0.10, 25)
    T_true = invert_T(world.pose(4))
    alone = optimize_frame_pose(current, odometry.T_cam_world, map_kps, p_map, PoseOptimizerConfig()).T_cam_world
    filtered = _filtered(current, odometry, map_kps, p_map, PoseEstimate(T_last, np.zeros((6, 6))))
    error_alone, _ = pose_errors(invert_T(alone), invert_T(T_true))
    error_filtered, _ = pose_errors(invert_T(filtered), invert_T(T_true))
    assert error_alone > 0.08 and error_filtered < 0.5 * error_alone, (error_alone, error_filtered)


def test_a_last_frame_known_loosely_gives_way_to_a_good_map() -> None:
    """The last frame 6 cm off with a 5 cm standard deviation (a relocalisation on a few far points):
    its VO points, taken as exact, hold the frame there; the filter lets 300 good map points place it."""
    world = PointWorld(seed=8)
    T_last_true = invert_T(world.pose(3))
    T_last = se3_exp(np.array([0.0, 0.0, 0.0, 0.06, 0.0, 0.0])) @ T_last_true
    current, odometry, map_kps, p_map = _odometry_and_map(world, T_last, 0.0, 300)
    T_true = invert_T(world.pose(4))
    joint, _ = optimise_with_odometry(current, odometry.T_cam_world, map_kps, p_map, odometry, PoseOptimizerConfig())
    loose = PoseEstimate(T_last, np.diag([1e-4] * 3 + [0.05**2] * 3))
    filtered = _filtered(current, odometry, map_kps, p_map, loose)
    error_joint, _ = pose_errors(invert_T(joint), invert_T(T_true))
    error_filtered, _ = pose_errors(invert_T(filtered), invert_T(T_true))
    assert error_joint > 0.02 and error_filtered < 0.01 and error_filtered < 0.3 * error_joint, (error_joint, error_filtered)


def test_vo_points_are_the_last_frames_near_depths_without_a_valid_map_point() -> None:
    """``last_frame_points``: map points of the last frame where still valid, then VO points at every
    other keypoint with a depth nearer than the threshold (nearest first, at least ``max_points``),
    back-projected from the last frame's pose."""
    from zenslam.frontend.visual_odometry import last_frame_points

    world = PointWorld(seed=9)
    last = world.frame(2)
    T_cam_world = invert_T(world.pose(2))
    n = len(last.features)
    rows = np.full(n, -1, dtype=np.int64)
    with_depth = np.flatnonzero(last.depth_m > 0)
    with_depth = with_depth[np.argsort(last.depth_m[with_depth], kind="stable")]
    rows[with_depth[:40]] = np.arange(40)  # the 40 nearest keypoints on map rows 0..39, rows 30..39 culled
    valid = np.arange(40) < 30
    map_p, map_desc = np.zeros((40, 3)), np.zeros((40, 32), np.uint8)
    close_m = 8.0
    points = last_frame_points(last, rows, T_cam_world, map_p, map_desc, valid, close_m, 100)
    assert np.array_equal(points.keypoints[:30], np.sort(with_depth[:30])) and np.array_equal(points.rows[:30], rows[points.keypoints[:30]])
    vo = points.keypoints[30:]
    assert np.all(points.rows[30:] == -1) and not np.isin(with_depth[:30], vo).any()
    assert np.isin(with_depth[30:40], vo).all()  # culled map points give their keypoints back
    depths = last.depth_m[vo]
    assert np.all(np.diff(depths) >= 0) and len(vo) >= 100
    free = np.setdiff1d(with_depth, with_depth[:30])
    assert np.array_equal(np.sort(vo[depths <= close_m]), np.sort(free[last.depth_m[free] <= close_m]))
    expected = (np.column_stack([last.features.px[vo], np.ones(len(vo))]) - [CAL.cx, CAL.cy, 0]) / [CAL.fx, CAL.fy, 1]
    p_cam = points.p_world[30:] @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    assert np.allclose(p_cam[:, :2] / p_cam[:, 2:], expected[:, :2], atol=1e-9)
    assert np.allclose(p_cam[:, 2], depths, atol=1e-6)
    none = last_frame_points(last, rows, T_cam_world, map_p, map_desc, valid, -1.0, 0)
    assert len(none.keypoints) == 30  # no VO point asked for


def test_few_map_points_and_the_vo_points_place_the_frame() -> None:
    """A last frame left with 16 valid map points (the rest withheld): with its VO points the
    motion-model match finds the map points and places the frame within a centimetre; without them
    there are too few matches for a pose."""
    from zenslam.pose_optimizer import PoseOptimizerConfig
    from zenslam.frontend.visual_odometry import last_frame_points, track_last_frame

    world = PointWorld(seed=10)
    last, current = world.frame(5), world.frame(6)
    T_last, T_true = invert_T(world.pose(5)), invert_T(world.pose(6))
    with_depth = np.flatnonzero(last.depth_m > 0)
    kept = with_depth[last.depth_m[with_depth] < 15.0][:16]
    rows = np.full(len(last.features), -1, dtype=np.int64)
    rows[kept] = np.arange(16)
    from zenslam.frontend.keyframe import unproject_keypoints

    map_p = unproject_keypoints(last.features.px[kept], last.depth_m[kept], CAL, world.pose(5))
    map_desc = last.features.descriptors[kept]
    velocity = invert_T(world.pose(5)) @ world.pose(4)  # the motion model's prediction from the frame before
    predicted = velocity @ T_last
    args = (last, rows, T_last, map_p, map_desc, np.ones(16, dtype=bool))
    with_vo = track_last_frame(current, last, last_frame_points(*args, 8.0, 100), predicted, SEARCH, PoseOptimizerConfig())
    assert with_vo is not None and with_vo.n_map >= 10 and with_vo.n_total >= 100
    t_err, r_err = pose_errors(invert_T(with_vo.T_cam_world), invert_T(T_true))
    assert t_err < 0.01 and r_err < 0.1
    assert track_last_frame(current, last, last_frame_points(*args, -1.0, 0), predicted, SEARCH, PoseOptimizerConfig()) is None


def _replaced_by_the_backend(pipeline: FrontendPipeline, fraction: float, seed: int = 0):
    """A late map update in which the backend replaced ``fraction`` of the points the last frame
    matched (fused them into points of its own, at the same places): the cache's keyframes observe
    the new ids, the old ones are removed, and the last frame's matches to them are gone."""
    from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE, KeyframeCorrection, MapUpdate

    lm = pipeline.tracker.map
    matched = np.unique(pipeline.tracker.last_frame.rows[pipeline.tracker.last_frame.rows >= 0])
    rows = matched[np.random.default_rng(seed).random(len(matched)) < fraction]
    new_ids = BACKEND_POINT_ID_BASE + np.arange(len(rows), dtype=np.int64)
    renamed = dict(zip(lm.point_ids[rows].tolist(), new_ids.tolist()))
    keyframes = [lm.keyframe(int(s)) for s in lm.cached_slots()]
    corrections = tuple(
        KeyframeCorrection(kf.id, kf.T_world_cam, np.array([renamed.get(int(i), int(i)) for i in kf.map_point_ids], dtype=np.int64))
        for kf in keyframes
    )
    return MapUpdate(
        keyframe_id=keyframes[-1].id, stamp_ns=keyframes[-1].stamp_ns, keyframes=corrections, point_ids=new_ids,
        p_world=lm.p_world[rows].copy(), descriptors=lm.descriptors[rows].copy(), normals=lm.normals[rows].copy(),
        min_distance_m=lm.min_distance_m[rows].copy(), max_distance_m=lm.max_distance_m[rows].copy(),
        removed_point_ids=lm.point_ids[rows].copy(),
    )  # fmt: skip


@pytest.mark.parametrize("vo_points", [True, False])
def test_a_late_update_that_replaced_the_last_frames_points(monkeypatch, vo_points: bool) -> None:
    """After an update that replaced 99% of the last frame's points, the VO points let the motion
    model place the next frame (ORB-SLAM's fallback to the reference keyframe is not needed);
    without them the motion model has too few matches and the reference keyframe is tried."""
    from zenslam.frontend.visual_odometry import VisualOdometryConfig

    world = PointWorld(seed=3)
    config = TrackingConfig(visual_odometry=VisualOdometryConfig(in_slam_mode=vo_points))
    pipeline = _pipeline(config)
    for k in range(8):
        assert pipeline.track(world.frame(k)).state == "ok"
    pipeline.map_sync.apply(_replaced_by_the_backend(pipeline, 0.99))
    assert np.count_nonzero(pipeline.tracker.map.valid[pipeline.tracker.last_frame.rows[pipeline.tracker.last_frame.rows >= 0]]) < 20
    tried = []
    reference = pipeline.tracker.reference_tracking.track
    monkeypatch.setattr(
        pipeline.tracker.reference_tracking, "track", lambda frame, *args: tried.append(frame.index) or reference(frame, *args)
    )
    result = pipeline.track(world.frame(8))
    assert result.state == "ok" and tried == ([] if vo_points else [8])
    t_err, r_err = pose_errors(result.T_world_cam, invert_T(world.pose(0)) @ world.pose(8))
    assert t_err < 0.02 and r_err < 0.1
