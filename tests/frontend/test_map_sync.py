"""Map sync without the bus: the real tracker and the real backend in lockstep, each update applied before the next frame.

After every update the frontend's cache agrees with the backend's map on what the update listed
(keyframe poses and associations, point positions, descriptors, viewing directions, ranges), the
removed points and keyframes are gone from tracking, and tracking stays accurate with the
backend's corrections.
"""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.backend.node import BackendNode
from zenslam.frontend.node import keyframe_message
from zenslam.frontend.pipeline import FrontendConfig, FrontendPipeline
from zenslam.schemas import codec
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE
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
