"""Map sync without the bus: the real tracker and the real backend in lockstep, each update applied before the next frame.

After every update the frontend's cache agrees with the backend's map on what the update listed
(keyframe poses and associations, point positions, descriptors, viewing directions, ranges), the
removed points and keyframes are gone from tracking, and tracking stays accurate with the
backend's corrections.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from zenslam.backend.node import BackendNode
from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.map_sync import MapSync, restore_keyframes
from zenslam.frontend.node import FrontendNode, keyframe_message
from zenslam.frontend.orb_extractor import Features
from zenslam.frontend.tracking_state import LastFrame, TrackerState
from zenslam.geometry import invert_T, make_T, so3_exp
from zenslam.frontend.pipeline import FrontendConfig, FrontendPipeline
from zenslam.schemas import codec
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE, KeyframeCorrection, MapUpdate
from zenslam.schemas.relocalisation import MapPoints
from zenslam.service.evaluation.metrics import evaluate
from zenslam.backend.config import BackendConfig
from zenslam.service.sources import open_source
from zenslam.trajectory import Trajectory

FRAMES = 20
ATE_BOUND_M = 0.01  # the synthetic loop tracks to ~3 mm over its first frames


@pytest.fixture(scope="module", params=[False, True], ids=["answer_after_local_ba", "answer_before_local_ba"])
def synced_run(request):
    """Track FRAMES synthetic frames; every keyframe goes through the backend (over the codec, as on
    the bus) and its updates come back before the next frame: one, or with
    ``answer_before_local_ba`` the answer then the local BA's correction. Returns the checks made
    after each keyframe's last update."""
    source = open_source("synthetic")
    pipeline = FrontendPipeline(FrontendConfig(), source.calibration, source.sensor)
    backend = BackendNode.from_config(BackendConfig(answer_before_local_ba=request.param))
    checks, poses = [], []
    for i, frame in enumerate(source):
        if i >= FRAMES:
            break
        out = pipeline.step(frame.index, frame.stamp_ns, frame.left, right=frame.right)
        assert out.state == "ok", (i, out.lost_reason)
        poses.append((frame.stamp_ns, out.T_world_cam))
        if out.keyframe is None:
            continue
        sent = codec.encode_keyframe(keyframe_message(out.keyframe, source.calibration, source.sensor))
        for update in backend.step(codec.decode_keyframe(sent)).updates:
            update = codec.decode_map_update(codec.encode_map_update(update))
            pipeline.apply_map_update(update)
        checks.append((update, _disagreements(pipeline.tracker.map, backend.mapper.map, update)))
    trajectory = Trajectory(np.array([s for s, _ in poses], dtype=np.int64), np.stack([T for _, T in poses]))
    return checks, trajectory, source.ground_truth(), pipeline, backend


def _disagreements(local_map, bmap, update) -> list[str]:
    """Where the frontend's cache differs from the backend's map on what ``update`` listed."""
    problems = []
    rows = local_map.rows_of_ids(update.point_ids)
    if (rows < 0).any() or not local_map.valid[rows].all():
        problems.append(f"{int((rows < 0).sum())} listed points missing, {int((~local_map.valid[rows[rows >= 0]]).sum())} invalid")
        return problems
    for name in ("p_world", "normals", "min_distance_m", "max_distance_m"):
        expected = np.array([getattr(bmap.points[p], name.removesuffix("s") if name == "normals" else name) for p in update.point_ids.tolist()])
        if name != "p_world":  # viewing directions and distances travel as float32
            expected = expected.astype(np.float32).astype(np.float64)
        if not np.array_equal(getattr(local_map, name)[rows], expected.reshape(getattr(local_map, name)[rows].shape)):
            problems.append(f"point {name} differ")
    if not np.array_equal(local_map.descriptors[rows], np.array([bmap.points[p].descriptor for p in update.point_ids.tolist()]).reshape(-1, 32)):
        problems.append("point descriptors differ")
    removed = local_map.rows_of_ids(update.removed_point_ids)
    if local_map.valid[removed[removed >= 0]].any():
        problems.append("removed points still valid")
    for correction in update.keyframes:
        slot = local_map.slot_of(correction.id)
        kf = local_map.keyframe(slot)
        # Poses travel as translation + quaternion: equal to rounding.
        if not np.allclose(kf.T_world_cam, bmap.keyframes[correction.id].T_world_cam, rtol=0.0, atol=1e-12):
            problems.append(f"keyframe {correction.id} pose differs")
        if not np.array_equal(kf.map_point_ids, bmap.keyframes[correction.id].map_point_ids):
            problems.append(f"keyframe {correction.id} associations differ")
        observed = set(local_map.point_ids[local_map.keyframe_point_rows(slot)].tolist())
        expected = {p for p in bmap.keyframes[correction.id].map_point_ids.tolist() if p >= 0}
        if observed != expected:
            problems.append(f"keyframe {correction.id} observes {len(observed)} points, the backend says {len(expected)}")
    for keyframe_id in update.removed_keyframe_ids.tolist():
        if local_map.slot_of(keyframe_id) >= 0:
            problems.append(f"removed keyframe {keyframe_id} still known")
    return problems


def test_the_cache_agrees_with_the_backend_after_every_update(synced_run):
    checks, *_ = synced_run
    assert len(checks) >= 4
    assert [problems for _, problems in checks] == [[] for _ in checks]


def test_updates_carry_backend_work_to_the_frontend(synced_run):
    checks, _, _, pipeline, backend = synced_run
    updates = [u for u, _ in checks]
    assert [u.keyframe_id for u in updates] == sorted(u.keyframe_id for u in updates)
    assert sum(len(u.keyframes) for u in updates) > len(updates)  # local BA moved older keyframes too
    created = {p for u in updates for p in u.point_ids.tolist() if p >= BACKEND_POINT_ID_BASE}
    assert created, "the backend triangulated no point"
    local_map = pipeline.tracker.map
    alive = [p for p in created if p in backend.mapper.map.points]
    rows = local_map.rows_of_ids(np.array(alive, dtype=np.int64))
    assert (rows >= 0).all() and local_map.valid[rows].all()


def test_tracking_with_the_backend_stays_accurate(synced_run):
    _, trajectory, truth, *_ = synced_run
    evaluation = evaluate(trajectory, truth)
    assert evaluation.ate.matched_poses == FRAMES
    assert evaluation.ate.rmse_m < ATE_BOUND_M


def test_applying_an_update_twice_changes_nothing(synced_run):
    checks, _, _, pipeline, _ = synced_run
    local_map = pipeline.tracker.map
    before = {name: getattr(local_map, name).copy() for name in ("p_world", "descriptors", "normals", "valid", "n_observations")}
    last, _ = checks[-1]
    pipeline.apply_map_update(last)
    for name, array in before.items():
        np.testing.assert_array_equal(getattr(local_map, name), array, err_msg=name)


# ---- map_sync's parts alone: the last frame, restored keyframes, the node's one call ----------------


def _keyframe(keyframe_id: int, point_ids, new_point_ids=(), centre=(0.0, 0.0, 0.0), seed: int = 0) -> KeyFrame:
    """A keyframe whose keypoints are associated with ``point_ids`` then ``new_point_ids`` (made by it)."""
    rng = np.random.default_rng(seed)
    ids = np.concatenate([np.asarray(point_ids, np.int64), np.asarray(new_point_ids, np.int64)])
    n, n_new = len(ids), len(new_point_ids)
    return KeyFrame(
        id=keyframe_id, frame_index=keyframe_id, stamp_ns=keyframe_id * 100_000_000,
        T_world_cam=make_T(np.eye(3), np.asarray(centre, dtype=float)),
        features=Features(
            px=rng.uniform(0, 600, (n, 2)).astype(np.float32), level=np.zeros(n, dtype=np.int16),
            angle_deg=np.zeros(n, dtype=np.float32), response=np.ones(n, dtype=np.float32),
            descriptors=rng.integers(0, 256, (n, 32), dtype=np.uint8), scale_factors=1.2 ** np.arange(8),
            inv_level_sigma2=1.2 ** (-2.0 * np.arange(8)),
        ),
        right_u=np.full(n, -1, dtype=np.float32), depth_m=np.full(n, -1, dtype=np.float32), map_point_ids=ids,
        new_point_ids=np.asarray(new_point_ids, np.int64), new_point_keypoints=np.arange(n - n_new, n, dtype=np.int64),
        new_points_world=np.asarray(centre) + rng.uniform([-2, -1, 4], [2, 1, 8], (n_new, 3)),
    )  # fmt: skip


def test_an_update_moves_the_last_frame_with_its_reference_keyframe():
    """ORB-SLAM2's UpdateLastFrame: the last frame keeps its pose relative to the reference keyframe
    the update moved, so the motion model predicts in the corrected map."""
    local_map = LocalMap()
    local_map.insert_keyframe(_keyframe(0, [], np.arange(20)))
    state = TrackerState(camera_fps=10.0, reference_slot=0)
    T_cam_world = invert_T(make_T(np.eye(3), np.array([0.3, 0.0, 0.1])))
    state.last = LastFrame(SimpleNamespace(index=4), np.full(20, -1, dtype=np.int64), T_cam_world)
    T_last_ref = state.last.T_cam_world @ local_map.keyframe(0).T_world_cam
    moved = make_T(so3_exp(np.array([0.0, 0.05, 0.0])), np.array([0.1, -0.2, 0.0]))
    correction = KeyframeCorrection(0, moved, local_map.keyframe(0).map_point_ids)
    MapSync(local_map, state).apply(MapUpdate(keyframe_id=0, stamp_ns=0, keyframes=(correction,)))
    np.testing.assert_array_equal(local_map.keyframe(0).T_world_cam, moved)
    np.testing.assert_allclose(state.last.T_cam_world @ moved, T_last_ref, atol=1e-12)
    state.reference_slot = -1  # no reference keyframe: the last frame stays where it is
    before = state.last.T_cam_world.copy()
    back = KeyframeCorrection(0, np.eye(4), correction.map_point_ids)
    MapSync(local_map, state).apply(MapUpdate(keyframe_id=0, stamp_ns=0, keyframes=(back,)))
    np.testing.assert_array_equal(state.last.T_cam_world, before)


def test_restored_keyframes_bring_their_points_and_count_only_those_they_bring():
    """A keyframe of the backend's map restored into the cache observes its points; it counts in
    ``n_observations`` only of the points it brings (the others count it already), it is no new
    keyframe (``n_keyframes`` stays), and a keyframe held already stays as it is."""
    local_map = LocalMap()
    held = _keyframe(0, [], np.arange(10))
    local_map.insert_keyframe(held)
    brought = BACKEND_POINT_ID_BASE + np.arange(3)
    backend_keyframe = _keyframe(7, np.concatenate([np.arange(5), brought]), centre=(0.5, 0.0, 0.0), seed=1)
    ids = np.concatenate([np.arange(5), brought])
    points = MapPoints(ids, np.tile([0.0, 0.0, 5.0], (8, 1)), np.zeros((8, 32), np.uint8), np.tile([0.0, 0.0, 1.0], (8, 1)),
                       np.full(8, 0.5), np.full(8, 20.0))  # fmt: skip
    slots = restore_keyframes(local_map, [backend_keyframe, held], points)
    assert slots == [1] and local_map.slot_of(7) == 1 and local_map.n_keyframes == 1
    rows = local_map.rows_of_ids(ids)
    assert (rows >= 0).all() and local_map.valid[rows].all()
    assert local_map.n_observations[rows].tolist() == [1] * 5 + [1] * 3  # the held points count it already
    np.testing.assert_array_equal(local_map.p_world[rows], points.p_world)  # the backend's values
    assert set(local_map.point_ids[local_map.keyframe_point_rows(1)].tolist()) == set(ids.tolist())
    assert restore_keyframes(local_map, [backend_keyframe], points) == []  # held now: nothing to restore


def test_the_node_applies_an_update_in_one_call_to_the_pipelines_map_sync():
    """The node hands a map update to the pipeline's ``map_sync`` directly, not through the pipeline."""
    applied: list[MapUpdate] = []

    class Pipeline:
        map_sync = SimpleNamespace(apply=applied.append)

        def apply_map_update(self, update):
            raise AssertionError("the update went through the pipeline")

    node = FrontendNode(lambda calibration, sensor: Pipeline())
    node._pipeline, node._map_sync = Pipeline(), Pipeline.map_sync  # as ``handle`` builds them on the first frame
    update = MapUpdate(keyframe_id=3, stamp_ns=0)
    node.apply_map_update(update)
    assert applied == [update] and node.updates_applied == 1 and node.answers_applied == 1
