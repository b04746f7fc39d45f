"""Relocalisation on synthetic keypoints with known 3D truth: a frame near a keyframe is placed, an
unrelated one is not; the tracker relocalises a lost frame on the old map and starts a new map only
after ``reinit_after_lost_frames`` frames without success."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.errors import ConfigError
from zenslam.frontend.frame import Frame
from zenslam.frontend.local_map import LocalMapConfig
from zenslam.frontend.orb_extractor import Features
from zenslam.frontend.relocalisation import PosePrior, RelocalisationConfig, as_keyframe, pose_offset, relocalise
from zenslam.frontend.config import FrontendConfig
from zenslam.frontend.keyframe_decision import KeyframeDecisionConfig
from zenslam.frontend.pipeline import FrontendPipeline
from zenslam.frontend.tracker import Tracker, TrackingConfig
from zenslam.pose_optimizer import PoseOptimizerConfig
from zenslam.frontend.visual_odometry import VisualOdometryConfig
from zenslam.geometry import invert_T, make_T, so3_exp, so3_log
from zenslam.map_point_rules import scale_invariance_range
from zenslam.schemas.relocalisation import (
    MapKeyframe,
    MapPoints,
    RelocalisationCandidate,
    RelocalisationCandidates,
    RelocalisationQuery,
)
from zenslam.vocabulary import BowVector, FeatureVector

CAL = PinholeCalibration(fx=450.0, fy=450.0, cx=320.0, cy=240.0, width=640, height=480, baseline_m=0.12)
SCALES = 1.2 ** np.arange(8)


class TwoByteVocabulary:
    """A stand-in vocabulary of known behaviour: a descriptor's word is its first two bytes, its
    direct-index node its first byte (256 nodes, as a trained tree's level 2 has about 100)."""

    def transform(self, descriptors: np.ndarray) -> tuple[BowVector, FeatureVector]:
        d = np.asarray(descriptors, dtype=np.uint8).reshape(-1, 32)
        words, counts = np.unique(d[:, 0].astype(np.int64) * 256 + d[:, 1], return_counts=True)
        weights = counts / max(counts.sum(), 1)
        nodes = np.unique(d[:, 0]).astype(np.int64)
        features = tuple(np.flatnonzero(d[:, 0] == n).astype(np.int64) for n in nodes)
        return BowVector(words, weights.astype(np.float64)), FeatureVector(nodes, features)

    def score(self, a: BowVector, b: BowVector) -> float:
        words = np.union1d(a.word_ids, b.word_ids)
        va, vb = np.zeros(len(words)), np.zeros(len(words))
        va[np.searchsorted(words, a.word_ids)] = a.weights
        vb[np.searchsorted(words, b.word_ids)] = b.weights
        return float(1.0 - 0.5 * np.abs(va - vb).sum())


VOCABULARY = TwoByteVocabulary()


class Scene:
    """Random points with descriptors, orientations and physical sizes; views of them with noise."""

    def __init__(self, seed: int, n_points: int = 3000, ring: bool = False) -> None:
        rng = np.random.default_rng(seed)
        if ring:  # all around the origin, 5-12 m away
            theta, r = rng.uniform(0, 2 * np.pi, n_points), rng.uniform(5, 12, n_points)
            self.p_world = np.column_stack([r * np.sin(theta), rng.uniform(-3, 3, n_points), r * np.cos(theta)])
        else:  # in front of the origin
            self.p_world = np.column_stack([rng.uniform(-8, 8, n_points), rng.uniform(-3, 3, n_points), rng.uniform(3, 16, n_points)])
        self.descriptors = rng.integers(0, 256, (n_points, 32), dtype=np.uint8)
        self.angles = rng.uniform(0, 360, n_points)
        self.size_constant = rng.uniform(3.0, 3.0 * 1.2**4, n_points)
        self.ids = 1000 + np.arange(n_points, dtype=np.int64)

    def view(self, T_world_cam: np.ndarray, seed: int, index: int = 0, keep: float = 0.8, n_fake: int = 150):
        """(Frame, point index of each keypoint (-1 for distractors)) seen from ``T_world_cam``."""
        rng = np.random.default_rng(seed)
        T_cam_world = invert_T(T_world_cam)
        p_cam = self.p_world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        z = p_cam[:, 2]
        safe_z = np.where(z > 0.1, z, 0.1)
        u, v = CAL.fx * p_cam[:, 0] / safe_z + CAL.cx, CAL.fy * p_cam[:, 1] / safe_z + CAL.cy
        seen = (z > 0.5) & (u >= 5) & (u < CAL.width - 5) & (v >= 5) & (v < CAL.height - 5) & (rng.random(len(z)) < keep)
        idx = np.flatnonzero(seen)
        n = len(idx)
        px = np.column_stack([u[idx], v[idx]]) + rng.normal(0.0, 0.3, (n, 2))
        level = np.clip(np.floor(np.log(self.size_constant[idx] / z[idx]) / np.log(1.2)), 0, 7).astype(np.int16)
        desc = self.descriptors[idx].copy()
        flips = rng.integers(0, 256, (n, 3))
        for j in range(3):
            desc[np.arange(n), flips[:, j] // 8] ^= (1 << (flips[:, j] % 8)).astype(np.uint8)
        disparity = CAL.bf / z[idx] + rng.normal(0.0, 0.2, n)
        stereo = (disparity > 1.0) & (rng.random(n) < 0.7)
        px = np.vstack([px, rng.uniform([0, 0], [CAL.width, CAL.height], (n_fake, 2))])
        level = np.concatenate([level, rng.integers(0, 8, n_fake).astype(np.int16)])
        desc = np.vstack([desc, rng.integers(0, 256, (n_fake, 32), dtype=np.uint8)])
        angles = np.concatenate([self.angles[idx] + rng.normal(0, 2.0, n), rng.uniform(0, 360, n_fake)]) % 360.0
        right_u = np.concatenate([np.where(stereo, px[:n, 0] - disparity, -1.0), np.full(n_fake, -1.0)])
        depth = np.concatenate([np.where(stereo, CAL.bf / np.maximum(disparity, 1e-6), -1.0), np.full(n_fake, -1.0)])
        features = Features(
            px=px.astype(np.float32), level=level, angle_deg=angles.astype(np.float32),
            response=np.ones(len(px), np.float32), descriptors=desc, scale_factors=SCALES, inv_level_sigma2=1.0 / SCALES**2,
        )  # fmt: skip
        frame = Frame(index, index * 50_000_000, CAL, features, right_u.astype(np.float32), depth.astype(np.float32))
        return frame, np.concatenate([idx, np.full(n_fake, -1)])

    def keyframe(self, kf_id: int, T_world_cam: np.ndarray, seed: int) -> tuple[MapKeyframe, MapPoints]:
        """A map keyframe seen from ``T_world_cam`` observing its points, and those points."""
        frame, idx = self.view(T_world_cam, seed)
        feats = frame.features
        keyframe = MapKeyframe(
            id=kf_id, stamp_ns=kf_id, T_world_cam=T_world_cam, keypoints_px=feats.px, levels=feats.level,
            angles_deg=feats.angle_deg, right_u=frame.right_u, depth_m=frame.depth_m, descriptors=feats.descriptors,
            map_point_ids=np.where(idx >= 0, self.ids[np.maximum(idx, 0)], -1), scale_factors=SCALES,
        )  # fmt: skip
        seen = idx >= 0
        order = np.argsort(idx[seen])
        pts = idx[seen][order]
        rays = self.p_world[pts] - T_world_cam[:3, 3]
        dist = np.linalg.norm(rays, axis=1)
        lo, hi = scale_invariance_range(dist, feats.level[seen][order], 1.2, 8)
        points = MapPoints(self.ids[pts], self.p_world[pts], self.descriptors[pts], rays / dist[:, None], lo, hi)
        return keyframe, points


def _merge(*points: MapPoints) -> MapPoints:
    ids = np.concatenate([p.ids for p in points])
    _, first = np.unique(ids, return_index=True)
    fields = ("ids", "p_world", "descriptors", "normals", "min_distance_m", "max_distance_m")
    return MapPoints(*(np.concatenate([getattr(p, f) for p in points])[first] for f in fields))


def pose_errors(T_cam_world_est: np.ndarray, T_world_cam_true: np.ndarray) -> tuple[float, float]:
    delta = T_world_cam_true @ T_cam_world_est
    return float(np.linalg.norm(delta[:3, 3])), float(np.degrees(np.linalg.norm(so3_log(delta[:3, :3]))))


T_KF = make_T(so3_exp(np.array([0.0, 0.2, 0.0])), np.array([0.5, 0.0, -1.0]))
T_NEAR = T_KF @ make_T(so3_exp(np.array([0.02, -0.12, 0.05])), np.array([0.3, -0.05, 0.4]))


@pytest.fixture(scope="module")
def place():
    scene = Scene(seed=0)
    keyframe, points = scene.keyframe(7, T_KF, seed=1)
    return scene, keyframe, points


def test_a_frame_near_a_keyframe_is_placed(place) -> None:
    scene, keyframe, points = place
    frame, truth = scene.view(T_NEAR, seed=2)
    reply = RelocalisationCandidates(frame.stamp_ns, (RelocalisationCandidate(7, 0.5),), (keyframe,), points)
    found = relocalise(frame, reply, VOCABULARY)
    assert found is not None and found.keyframe_id == 7 and found.candidates_tried == 1
    t_err, r_err = pose_errors(found.T_cam_world, T_NEAR)
    assert t_err < 0.01 and r_err < 0.1, (t_err, r_err)
    matched = np.flatnonzero(found.point_ids >= 0)
    assert found.n_inliers == len(matched) >= 50
    correct = found.point_ids[matched] == np.where(truth[matched] >= 0, scene.ids[np.maximum(truth[matched], 0)], -2)
    assert np.mean(correct) > 0.98


def test_an_unrelated_place_is_not_placed(place) -> None:
    _, keyframe, points = place
    elsewhere, _ = Scene(seed=5).view(T_NEAR, seed=3)
    reply = RelocalisationCandidates(0, (RelocalisationCandidate(7, 0.5),), (keyframe,), points)
    assert relocalise(elsewhere, reply, VOCABULARY) is None


def test_candidates_are_tried_best_first_until_one_holds(place) -> None:
    scene, keyframe, points = place
    other_kf, other_points = Scene(seed=6).keyframe(3, T_KF, seed=4)
    frame, _ = scene.view(T_NEAR, seed=2)
    candidates = (RelocalisationCandidate(3, 0.9), RelocalisationCandidate(7, 0.5))
    reply = RelocalisationCandidates(0, candidates, (other_kf, keyframe), _merge(points, other_points))
    found = relocalise(frame, reply, VOCABULARY)
    assert found is not None and found.keyframe_id == 7 and found.candidates_tried == 2
    assert relocalise(frame, dataclasses.replace(reply, candidates=candidates[:1]), VOCABULARY) is None


def test_guided_search_finds_the_points_bag_of_words_missed(place) -> None:
    """Keyframe keypoints far (in bits) from the frame's keep their points' descriptors: only the search
    by projection with the first pose can match them."""
    scene, keyframe, points = place
    rng = np.random.default_rng(7)
    desc = keyframe.descriptors.copy()
    spoiled = rng.random(len(desc)) < 0.985
    desc[spoiled] ^= rng.integers(0, 256, (int(spoiled.sum()), 32), dtype=np.uint8) | np.uint8(0x11)
    frame, _ = scene.view(T_NEAR, seed=2)
    reply = RelocalisationCandidates(0, (RelocalisationCandidate(7, 0.5),), (dataclasses.replace(keyframe, descriptors=desc),), points)
    found = relocalise(frame, reply, VOCABULARY)
    assert found is not None
    assert found.n_bow_matches < RelocalisationConfig().min_inliers < found.n_inliers
    t_err, r_err = pose_errors(found.T_cam_world, T_NEAR)
    assert t_err < 0.01 and r_err < 0.1, (t_err, r_err)


def test_too_few_bag_of_words_matches_skip_the_candidate(place) -> None:
    scene, keyframe, points = place
    frame, _ = scene.view(T_NEAR, seed=2)
    reply = RelocalisationCandidates(0, (RelocalisationCandidate(7, 0.5),), (keyframe,), points)
    assert relocalise(frame, reply, VOCABULARY, RelocalisationConfig(min_bow_matches=100_000)) is None


def test_relocalisation_is_deterministic(place) -> None:
    scene, keyframe, points = place
    frame, _ = scene.view(T_NEAR, seed=2)
    reply = RelocalisationCandidates(0, (RelocalisationCandidate(7, 0.5),), (keyframe,), points)
    a, b = relocalise(frame, reply, VOCABULARY), relocalise(frame, reply, VOCABULARY)
    assert np.array_equal(a.T_cam_world, b.T_cam_world) and np.array_equal(a.point_ids, b.point_ids)


def test_pose_offset_is_the_distance_of_the_centres_and_the_angle_between_the_rotations() -> None:
    T_a = invert_T(make_T(so3_exp(np.array([0.0, 0.3, 0.0])), np.array([1.0, 2.0, 3.0])))
    T_b = invert_T(make_T(so3_exp(np.array([0.0, 0.3, 0.0])) @ so3_exp(np.array([0.1, 0.0, 0.0])), np.array([1.0, 2.0, 3.5])))
    distance, angle = pose_offset(T_a, T_b)
    assert distance == pytest.approx(0.5) and angle == pytest.approx(np.degrees(0.1))
    assert pose_offset(T_a, T_a) == pytest.approx((0.0, 0.0), abs=1e-6)


def test_a_prior_refuses_a_candidate_pose_far_from_it_and_admits_one_near_it(place) -> None:
    scene, keyframe, points = place
    frame, _ = scene.view(T_NEAR, seed=2)
    reply = RelocalisationCandidates(frame.stamp_ns, (RelocalisationCandidate(7, 0.5),), (keyframe,), points)
    T_cam_near = invert_T(T_NEAR)
    near = invert_T(T_NEAR @ make_T(so3_exp(np.array([0.0, 0.05, 0.0])), np.array([0.2, 0.0, 0.0])))
    assert relocalise(frame, reply, VOCABULARY, prior=PosePrior(near, 0.3, 5.0)) is not None
    assert relocalise(frame, reply, VOCABULARY, prior=PosePrior(near, 0.1, 5.0)) is None  # 0.2 m away
    assert relocalise(frame, reply, VOCABULARY, prior=PosePrior(near, 0.3, 2.0)) is None  # 2.9 degrees away
    assert PosePrior(T_cam_near, 0.0, 0.0).admits(T_cam_near)


def test_a_map_keyframe_becomes_a_cache_keyframe(place) -> None:
    _, keyframe, _ = place
    kf = as_keyframe(keyframe)
    assert kf.id == 7 and kf.n_keypoints == len(keyframe.keypoints_px) and len(kf.new_point_ids) == 0
    np.testing.assert_array_equal(kf.map_point_ids, keyframe.map_point_ids)
    np.testing.assert_allclose(kf.features.inv_level_sigma2, 1.0 / SCALES**2)


# ---- the tracker's state machine -------------------------------------------------------------------


def path_pose(k: int) -> np.ndarray:
    """T_world_cam of frame k: turning on the spot (2.3 degrees per frame) with a little sideways sway."""
    return make_T(so3_exp(np.array([0.0, 0.04 * k, 0.0])), np.array([0.2 * np.sin(0.1 * k), 0.0, 0.0]))


class FakeBackend:
    """The backend's side of relocalisation: every keyframe the tracker made, with its points as the
    tracker created them; candidates best first by bag-of-words score, neighbours by shared points."""

    def __init__(self, tracker: Tracker) -> None:
        self.tracker = tracker
        self.keyframes: dict[int, MapKeyframe] = {}
        self.points: dict[int, tuple] = {}
        self.queries: list[RelocalisationQuery] = []
        self.answer = True

    def record(self, keyframe) -> None:
        if keyframe is None:
            return
        self.keyframes[keyframe.id] = MapKeyframe(
            keyframe.id, keyframe.stamp_ns, keyframe.T_world_cam, keyframe.px, keyframe.level, keyframe.angle_deg,
            keyframe.right_u, keyframe.depth_m, keyframe.descriptors, keyframe.map_point_ids, SCALES,
        )  # fmt: skip
        lm = self.tracker.map
        ids = keyframe.map_point_ids[keyframe.map_point_ids >= 0]
        rows = lm.rows_of_ids(ids)
        for point_id, row in zip(ids.tolist(), rows.tolist()):
            if row >= 0:
                self.points[point_id] = (lm.p_world[row].copy(), lm.descriptors[row].copy(), lm.normals[row].copy(),
                                         lm.min_distance_m[row], lm.max_distance_m[row])  # fmt: skip

    def __call__(self, query: RelocalisationQuery) -> RelocalisationCandidates | None:
        self.queries.append(query)
        if not self.answer:
            return RelocalisationCandidates(query.stamp_ns)
        bow = BowVector(query.word_ids, query.weights)
        ranked = sorted(self.keyframes, key=lambda k: (-VOCABULARY.score(bow, VOCABULARY.transform(self.keyframes[k].descriptors)[0]), k))
        candidates = []
        for k in ranked[: query.max_candidates]:
            shared = {o: len(np.intersect1d(self._ids(k), self._ids(o))) for o in self.keyframes if o != k}
            neighbours = sorted((o for o in shared if shared[o] > 0), key=lambda o: (-shared[o], o))[: query.max_neighbours]
            candidates.append(RelocalisationCandidate(k, 1.0, np.asarray(neighbours, np.int64)))
        listed = sorted({c.keyframe_id for c in candidates} | {int(o) for c in candidates for o in c.neighbour_ids})
        ids = sorted({int(p) for k in listed for p in self._ids(k) if int(p) in self.points})
        values = [self.points[p] for p in ids]
        points = MapPoints(
            np.asarray(ids, np.int64), np.array([v[0] for v in values]).reshape(-1, 3), np.array([v[1] for v in values]).reshape(-1, 32),
            np.array([v[2] for v in values]).reshape(-1, 3), np.array([v[3] for v in values]), np.array([v[4] for v in values]),
        )  # fmt: skip
        return RelocalisationCandidates(query.stamp_ns, tuple(candidates), tuple(self.keyframes[k] for k in listed), points)

    def _ids(self, k: int) -> np.ndarray:
        ids = self.keyframes[k].map_point_ids
        return ids[ids >= 0]


def _pipeline(sensor: str, config: TrackingConfig, camera_fps: float = 10.0) -> FrontendPipeline:
    """A pipeline tracking built frames with ``config``, the tracker's default pose and keyframe
    settings and the test vocabulary, at ``camera_fps``."""
    frontend = FrontendConfig(tracking=config, pose=PoseOptimizerConfig(), keyframe=KeyframeDecisionConfig())
    pipeline = FrontendPipeline(frontend, CAL, sensor, vocabulary=VOCABULARY)
    pipeline.tracker.camera_fps = camera_fps
    return pipeline


def _tracker(camera_fps: float = 10.0, **tracking) -> tuple[FrontendPipeline, FakeBackend, Scene]:
    pipeline = _pipeline("stereo", TrackingConfig(**tracking), camera_fps)
    return pipeline, FakeBackend(pipeline.tracker), Scene(seed=11, n_points=12000, ring=True)


def _blind(frame: Frame) -> Frame:
    """The frame with every descriptor replaced: nothing in it matches the map."""
    rng = np.random.default_rng(frame.index)
    features = dataclasses.replace(frame.features, descriptors=rng.integers(0, 256, frame.features.descriptors.shape, dtype=np.uint8))
    return dataclasses.replace(frame, features=features)


def _track(pipeline, backend, frame):
    result = pipeline.track(frame, candidates=backend)
    backend.record(result.keyframe)
    return result


def test_a_lost_tracker_relocalises_on_the_old_map_even_when_its_cache_evicted_the_place() -> None:
    # A cache of a few keyframes: the start of the path is evicted long before the camera comes back.
    cache = LocalMapConfig(cache_max_keyframes=3, cache_margin_keyframes=0, cache_min_keyframes_between_evictions=1)
    pipeline, backend, scene = _tracker(local_map=cache)
    T0 = path_pose(0)
    for k in range(80):  # half a turn
        assert _track(pipeline, backend, scene.view(path_pose(k), seed=k, index=k)[0]).state == "ok", k
    assert pipeline.tracker.map.slot_of(0) < 0 and pipeline.tracker.eviction.passes > 0
    assert _track(pipeline, backend, _blind(scene.view(path_pose(80), seed=80, index=80)[0])).state == "lost"
    assert backend.queries == []  # the frame that lost tracking is not relocalised
    # Kidnapped: the camera is back near the start of the path, whose keyframes the cache evicted.
    back = _track(pipeline, backend, scene.view(path_pose(2), seed=81, index=81)[0])
    assert back.state == "ok" and back.relocalised and back.T_world_cam is not None
    assert len(backend.queries) == 1 and backend.queries[0].stamp_ns == 81 * 50_000_000
    t_err, r_err = pose_errors(invert_T(back.T_world_cam), invert_T(T0) @ path_pose(2))
    assert t_err < 0.02 and r_err < 0.2, (t_err, r_err)
    assert pipeline.tracker.n_relocalisations == 1 and pipeline.tracker.n_reinitialisations == 0
    assert pipeline.tracker.map.slot_of(0) >= 0  # the old place is cached again
    assert not pipeline.tracker.motion.has_velocity  # the motion model restarts
    for k in range(3, 8):  # and tracking goes on there, on the old map
        result = _track(pipeline, backend, scene.view(path_pose(k), seed=82 + k, index=79 + k)[0])
        assert result.state == "ok" and not result.relocalised
        t_err, _ = pose_errors(invert_T(result.T_world_cam), invert_T(T0) @ path_pose(k))
        assert t_err < 0.02


def test_a_new_map_starts_only_after_reinit_after_lost_frames_without_success() -> None:
    pipeline, backend, scene = _tracker(reinit_after_lost_frames=3)
    for k in range(6):
        assert _track(pipeline, backend, scene.view(path_pose(k), seed=k, index=k)[0]).state == "ok"
    backend.answer = False  # the backend knows no place like it
    states = [_track(pipeline, backend, _blind(scene.view(path_pose(k), seed=k, index=k)[0])) for k in range(6, 9)]
    assert [s.state for s in states] == ["lost"] * 3
    assert [s.lost_reason for s in states[1:]] == ["relocalisation_no_candidates"] * 2
    restart = _track(pipeline, backend, scene.view(path_pose(9), seed=9, index=9)[0])
    assert restart.state == "initializing" and restart.keyframe is not None
    assert len(backend.queries) == 3  # frames 7, 8 and 9 asked; frame 6 lost tracking
    assert pipeline.tracker.n_reinitialisations == 1 and pipeline.tracker.n_relocalisations == 0


def test_a_frame_without_keypoints_asks_nothing() -> None:
    pipeline, backend, scene = _tracker()
    for k in range(4):
        _track(pipeline, backend, scene.view(path_pose(k), seed=k, index=k)[0])
    _track(pipeline, backend, _blind(scene.view(path_pose(4), seed=4, index=4)[0]))
    frame = scene.view(path_pose(5), seed=5, index=5)[0]
    empty = Frame(5, frame.stamp_ns, CAL, frame.features.subset(np.zeros(0, np.int64)), np.zeros(0, np.float32), np.zeros(0, np.float32))
    result = _track(pipeline, backend, empty)
    assert result.state == "lost" and result.lost_reason == "relocalisation_no_keypoints" and backend.queries == []
    assert _track(pipeline, backend, scene.view(path_pose(6), seed=6, index=6)[0]).relocalised


def test_keyframes_pause_for_a_second_after_a_relocalisation_only_when_asked() -> None:
    def keyframes_after_relocalising(pause: bool) -> list[bool]:
        pipeline, backend, scene = _tracker(camera_fps=4.0, relocalisation=RelocalisationConfig(pause_keyframes=pause))
        for k in range(30):
            _track(pipeline, backend, scene.view(path_pose(k), seed=k, index=k)[0])
        assert pipeline.tracker.map.n_keyframes > 4  # past ORB-SLAM's condition: more keyframes than frames per second
        _track(pipeline, backend, _blind(scene.view(path_pose(30), seed=30, index=30)[0]))
        results = [_track(pipeline, backend, scene.view(path_pose(k), seed=k, index=k)[0]) for k in range(34, 44)]
        assert results[0].relocalised and all(r.state == "ok" for r in results)
        return [r.keyframe is not None for r in results]

    paused = keyframes_after_relocalising(True)
    assert not any(paused[:4]) and any(paused[4:])  # 4 frames: one second at 4 frames per second
    assert any(keyframes_after_relocalising(False)[:4])


def test_without_a_source_of_candidates_tracking_recovers_as_before() -> None:
    pipeline, _, scene = _tracker()
    for k in range(4):
        assert pipeline.track(scene.view(path_pose(k), seed=k, index=k)[0]).state == "ok"
    assert pipeline.track(_blind(scene.view(path_pose(4), seed=4, index=4)[0])).state == "lost"
    back = pipeline.track(scene.view(path_pose(5), seed=5, index=5)[0])
    assert back.state == "ok" and not back.relocalised


def _union(a: Scene, b: Scene) -> Scene:
    """One scene holding the points of both (``b``'s ids after ``a``'s)."""
    both = Scene.__new__(Scene)
    both.p_world = np.vstack([a.p_world, b.p_world])
    both.descriptors = np.vstack([a.descriptors, b.descriptors])
    both.angles = np.concatenate([a.angles, b.angles])
    both.size_constant = np.concatenate([a.size_constant, b.size_constant])
    both.ids = np.concatenate([a.ids, b.ids + len(a.ids)])
    return both


def test_localisation_leaves_visual_odometry_by_relocalising_and_says_so() -> None:
    """Localisation mode: where the map's points vanish the frames go on by visual odometry; the first
    frame that relocalises into the map again is flagged relocalised (metrics.json counts it) and
    restarts the motion model, whose velocity would otherwise hold the jump back onto the map."""
    pipeline, backend, mapped = _tracker(localization=True)
    unmapped = Scene(seed=12, n_points=12000, ring=True)
    both = _union(mapped, unmapped)
    views = [mapped] * 4 + [both] * 2 + [unmapped] * 4 + [both] * 2
    results = [_track(pipeline, backend, scene.view(path_pose(k), seed=k, index=k)[0]) for k, scene in enumerate(views[:11])]
    assert not pipeline.tracker.motion.has_velocity
    results.append(_track(pipeline, backend, both.view(path_pose(11), seed=11, index=11)[0]))
    assert [r.state for r in results] == ["ok"] * len(views)
    assert pipeline.tracker.map.n_keyframes == 1 and all(r.keyframe is None for r in results[1:])
    assert all(r.n_tracked < 10 and not r.relocalised for r in results[6:10])  # on visual odometry
    assert results[10].relocalised and results[10].n_tracked >= 30 and not results[11].relocalised
    T0 = path_pose(0)
    t_err, r_err = pose_errors(invert_T(results[10].T_world_cam), invert_T(T0) @ path_pose(10))
    assert t_err < 0.02 and r_err < 0.2, (t_err, r_err)


def _moved(reply: RelocalisationCandidates, shift: np.ndarray) -> RelocalisationCandidates:
    """The backend's reply with its keyframes and points moved by ``shift`` (metres): a place that
    looks like the frame's and lies elsewhere in the map."""
    keyframes = tuple(dataclasses.replace(kf, T_world_cam=make_T(kf.T_world_cam[:3, :3], kf.T_world_cam[:3, 3] + shift)) for kf in reply.keyframes)
    return dataclasses.replace(reply, keyframes=keyframes, points=dataclasses.replace(reply.points, p_world=reply.points.p_world + shift))


@pytest.mark.parametrize("agreement_m", [0.3, None])
def test_on_visual_odometry_a_relocalisation_far_from_the_odometry_pose_is_refused(agreement_m) -> None:
    """Localisation mode, on visual odometry: the place a relocalisation finds lies 1.5 m from where
    the odometry has the camera. Refused (the frame stays on odometry, near the truth) unless
    ``vo_agreement_m`` is None; a relocalisation where the odometry has it is taken either way."""
    pipeline, backend, mapped = _tracker(localization=True, relocalisation=RelocalisationConfig(vo_agreement_m=agreement_m))
    unmapped = Scene(seed=12, n_points=12000, ring=True)
    both = _union(mapped, unmapped)
    views = [mapped] * 4 + [both] * 2 + [unmapped] * 4
    results = [_track(pipeline, backend, scene.view(path_pose(k), seed=k, index=k)[0]) for k, scene in enumerate(views)]
    assert all(r.state == "ok" for r in results) and all(r.n_tracked < 10 for r in results[6:])  # on visual odometry
    shift = np.array([1.5, 0.0, 0.0])
    moved = pipeline.track(both.view(path_pose(10), seed=10, index=10)[0], candidates=lambda query: _moved(backend(query), shift))
    t_err, _ = pose_errors(invert_T(moved.T_world_cam), invert_T(path_pose(0)) @ path_pose(10))
    if agreement_m is None:
        assert moved.relocalised and abs(t_err - 1.5) < 0.05, t_err
        return
    assert moved.state == "ok" and not moved.relocalised and t_err < 0.05, t_err
    back = _track(pipeline, backend, both.view(path_pose(11), seed=11, index=11)[0])
    t_err, _ = pose_errors(invert_T(back.T_world_cam), invert_T(path_pose(0)) @ path_pose(11))
    assert back.relocalised and t_err < 0.02, t_err


def _bad_depths(frame: Frame, gain: float) -> Frame:
    """The frame with every stereo disparity multiplied by ``gain`` (its depths divided by it)."""
    u, has_depth = frame.features.px[:, 0], frame.depth_m > 0
    right_u = np.where(has_depth, u - gain * (u - frame.right_u), frame.right_u).astype(np.float32)
    depth = np.where(has_depth, frame.depth_m / gain, frame.depth_m).astype(np.float32)
    return dataclasses.replace(frame, right_u=right_u, depth_m=depth)


def _localise_off_the_map(anchor_keep_ratio: float, bad_frame: int | None) -> list[np.ndarray]:
    """T_cam_world of each frame of a localisation run that leaves the map and goes on by visual
    odometry, with the depths of frame ``bad_frame`` 30% too far."""
    odometry = VisualOdometryConfig(anchor_keep_ratio=anchor_keep_ratio)
    pipeline, backend, mapped = _tracker(localization=True, visual_odometry=odometry)
    unmapped = Scene(seed=12, n_points=12000, ring=True)
    both = _union(mapped, unmapped)
    views = [mapped] * 4 + [both] * 2 + [unmapped] * 6
    poses = []
    for k, scene in enumerate(views):
        frame = scene.view(path_pose(k), seed=k, index=k)[0]
        result = _track(pipeline, backend, _bad_depths(frame, 0.7) if k == bad_frame else frame)
        assert result.state == "ok", k
        poses.append(invert_T(result.T_world_cam))
    assert pipeline.tracker.n_vo_frames >= 5
    return poses


def test_visual_odometry_places_frames_on_an_anchor_so_one_frames_bad_depths_do_not_carry_on() -> None:
    """Localisation mode off the map: frames on visual odometry are matched to the VO points of an
    anchor frame, not of the last frame, so a frame whose depths are off places only itself badly.
    Chained frame to frame (ORB-SLAM2, ``anchor_keep_ratio`` 1.0) its error passes to every later frame."""
    T0 = path_pose(0)

    def errors_mm(poses: list[np.ndarray], frames: range) -> list[float]:
        return [1e3 * pose_errors(poses[k], invert_T(T0) @ path_pose(k))[0] for k in frames]

    clean = _localise_off_the_map(0.5, None)
    anchored = _localise_off_the_map(0.5, 8)
    chained = _localise_off_the_map(1.0, 8)
    after = range(9, 12)
    for k in after:  # frame 8 never became the anchor: the frames after it are placed as without it
        assert np.allclose(anchored[k], clean[k], atol=1e-4), (k, anchored[k] - clean[k])
    assert max(errors_mm(anchored, after)) < 15.0, errors_mm(anchored, after)
    assert min(errors_mm(chained, after)) > 18.0, errors_mm(chained, after)


def test_a_pose_the_inliers_do_not_pin_down_is_refused_when_asked(place) -> None:
    """max_position_sigma_ratio: the near frame's pose, accepted by default, is refused once the
    allowed centre sigma is below what its inliers give; a loose bound keeps it."""
    scene, keyframe, points = place
    frame, _ = scene.view(T_NEAR, seed=2)
    reply = RelocalisationCandidates(frame.stamp_ns, (RelocalisationCandidate(7, 0.5),), (keyframe,), points)
    assert relocalise(frame, reply, VOCABULARY, RelocalisationConfig(max_position_sigma_ratio=0.05)) is not None
    assert relocalise(frame, reply, VOCABULARY, RelocalisationConfig(max_position_sigma_ratio=1e-6)) is None
    with pytest.raises(ConfigError, match="max_position_sigma_ratio"):
        RelocalisationConfig(max_position_sigma_ratio=0.0)


@pytest.mark.parametrize(("max_sigma_m", "sensor"), [(10.0, "stereo"), (None, "stereo"), (10.0, "rgbd")])
def test_localising_in_a_saved_map_weighs_its_points_by_their_covariance(max_sigma_m, sensor) -> None:
    """A stereo localisation run entering a map another run made: the points of the keyframes it
    brings into its cache get their covariance from those keyframes' observations (zeros, points
    exact, when ``localization_point_max_sigma_m`` is None, or for an RGB-D camera), and the
    relocalised pose is as good."""
    mapper, backend, scene = _tracker()
    for k in range(12):
        assert _track(mapper, backend, scene.view(path_pose(k), seed=k, index=k)[0]).state == "ok"
    config = TrackingConfig(
        localization=True, start_in_map=True, localization_point_max_sigma_m=max_sigma_m,
        local_map=LocalMapConfig(keyframe_id_start=1000, point_id_start=1 << 40),
    )  # fmt: skip
    localiser = _pipeline(sensor, config)
    results = [localiser.track(scene.view(path_pose(k), seed=100 + k, index=k)[0], candidates=backend) for k in (3, 4, 5)]
    assert results[0].relocalised and all(r.state == "ok" for r in results)
    for k, r in zip((3, 4, 5), results):
        t_err, r_err = pose_errors(invert_T(r.T_world_cam), invert_T(path_pose(0)) @ path_pose(k))
        assert t_err < 0.02 and r_err < 0.2, (k, t_err, r_err)
    lm = localiser.tracker.map
    rows = np.unique(np.concatenate([lm.keyframe_point_rows(slot) for slot in lm.cached_slots()]))
    sigmas = np.sqrt(np.linalg.eigvalsh(lm.covariance[rows]))
    if max_sigma_m is None or sensor == "rgbd":
        assert not lm.covariance.any()
        return
    # Points 5-12 m away, seen by keyframes a few centimetres apart with a 12 cm baseline: known to
    # decimetres along their rays and to millimetres across them.
    assert len(rows) > 100 and np.all(sigmas > 0) and np.all(sigmas[:, -1] <= max_sigma_m)
    assert 0.05 < np.median(sigmas[:, -1]) < 2.0 and np.median(sigmas[:, 0]) < 0.02
