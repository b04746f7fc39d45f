"""The backend node: step on synthetic keyframes, the queryable replies and their codec, and serve over zenoh on loopback."""

from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest

from zenslam.backend.config import BackendConfig
from zenslam.backend.journal import Answered, JournaledKeyframe, JournalWriter, read_journal
from zenslam.backend.local_ba import BAProblem, BAResult
from zenslam.backend.local_mapping import TIMING_STEPS, LocalMapper, LocalMappingConfig, new_backend_map
from zenslam.backend.node import BackendNode, serve
from zenslam.runtime.backend_queries import query_map, query_trajectory
from zenslam.camera import PinholeCalibration
from zenslam.geometry import invert_T, make_T, transform_points
from zenslam.runtime import bus
from zenslam.schemas import codec, keys
from zenslam.schemas.codec import KeyframeMessage, MessageError

CAL = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)
STEP_M = 0.2  # camera motion between keyframes along +x, metres


class World:
    """Stereo keyframes of 300 known points seen by a camera moving along +x (looking along +z).

    Each visible point is a keypoint at its exact projection with the point's descriptor; a point
    seen for the first time is a new point (at its true position), later ones are associated.
    """

    def __init__(self, seed: int = 0, n_points: int = 300):
        rng = np.random.default_rng(seed)
        self.p = np.column_stack([rng.uniform(-3, 6, n_points), rng.uniform(-1.5, 1.5, n_points), rng.uniform(3, 9, n_points)])
        self.desc = rng.integers(0, 256, (n_points, 32), dtype=np.uint8)
        self.known: set[int] = set()

    def pose(self, k: int) -> np.ndarray:
        return make_T(np.eye(3), [k * STEP_M, 0.0, 0.0])

    def keyframe(self, k: int) -> KeyframeMessage:
        T = self.pose(k)
        p_cam = transform_points(invert_T(T), self.p)
        z = p_cam[:, 2]
        px = CAL.fx * p_cam[:, :2] / z[:, None] + [CAL.cx, CAL.cy]
        vis = np.flatnonzero((z > 0.5) & (px[:, 0] >= 0) & (px[:, 0] < 640) & (px[:, 1] >= 0) & (px[:, 1] < 480))
        new = np.array([i for i in vis.tolist() if i not in self.known], dtype=np.int64)
        self.known.update(vis.tolist())
        n = len(vis)
        return KeyframeMessage(
            id=k, stamp_ns=k * 100_000_000, frame_index=3 * k, T_world_cam=T, calibration=CAL, sensor="stereo",
            keypoints_px=px[vis].astype(np.float32), levels=np.zeros(n, np.int16), angles_deg=np.zeros(n, np.float32),
            right_u=(px[vis, 0] - CAL.bf / z[vis]).astype(np.float32), depth_m=z[vis].astype(np.float32),
            descriptors=self.desc[vis], map_point_ids=vis.astype(np.int64), scale_factors=1.2 ** np.arange(8),
            new_point_ids=new, new_points_world=self.p[new].reshape(-1, 3),
        )  # fmt: skip


class IdentityAdjuster:
    """Local BA stand-in: keeps the window as it is, every observation an inlier."""

    def optimize(self, problem: BAProblem) -> BAResult:
        inliers = np.ones(len(problem.obs_keyframe), dtype=bool)
        return BAResult(problem.T_world_cam.copy(), problem.p_world.copy(), inliers, np.zeros(0, np.int64), {})


def _node() -> BackendNode:
    return BackendNode(LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), IdentityAdjuster()))


def test_step_returns_the_update_of_each_keyframe_and_its_timings():
    world, node = World(), _node()
    for k in range(4):
        update = node.step(world.keyframe(k)).updates[0]
        assert (update.keyframe_id, update.stamp_ns) == (k, k * 100_000_000)
        assert k in [c.id for c in update.keyframes]
    assert node.processed == 4 and not node.finished
    assert set(node.last_timings_ms) == set(TIMING_STEPS)
    assert all(ms >= 0 for ms in node.last_timings_ms.values())


def test_trajectory_and_snapshot_are_the_map_now():
    world, node = World(), _node()
    for k in range(5):
        node.step(world.keyframe(k))
    trajectory = node.trajectory()
    assert trajectory.keyframes_processed == 5 and not trajectory.finished
    bmap = node.mapper.map
    assert trajectory.keyframe_ids.tolist() == list(bmap.keyframes)
    np.testing.assert_array_equal(trajectory.stamps_ns, [bmap.keyframes[k].stamp_ns for k in bmap.keyframes])
    for k, T in zip(trajectory.keyframe_ids.tolist(), trajectory.T_world_cam):
        np.testing.assert_allclose(T, world.pose(k), atol=1e-9)  # identity BA: the poses as sent
    snapshot = node.snapshot()
    assert snapshot.point_ids.tolist() == sorted(bmap.points)
    assert len(snapshot.point_ids) > 100
    for point_id, p in zip(snapshot.point_ids.tolist()[:50], snapshot.p_world[:50]):
        np.testing.assert_array_equal(p, bmap.points[point_id].p_world)


def test_the_trajectory_names_the_ids_a_restarted_frontend_may_use_past_the_map_and_the_inbox():
    world, node = World(), _node()
    for k in range(4):
        node.step(world.keyframe(k))
    trajectory = codec.decode_keyframe_trajectory(codec.encode_keyframe_trajectory(node.trajectory()))
    assert trajectory.next_keyframe_id == 4
    assert trajectory.next_frontend_point_id == max(node.map.points) + 1
    waiting = [world.keyframe(4), world.keyframe(5)]  # sent, still in the inbox: their ids are taken too
    ahead = node.trajectory(waiting)
    assert ahead.next_keyframe_id == 6
    new_ids = np.concatenate([kf.new_point_ids for kf in waiting])
    assert ahead.next_frontend_point_id == max(int(new_ids.max()), max(node.map.points)) + 1


def test_replies_round_trip_exactly():
    world, node = World(), _node()
    for k in range(3):
        node.step(world.keyframe(k))
    snapshot = node.snapshot()
    back = codec.decode_map_snapshot(codec.encode_map_snapshot(snapshot))
    np.testing.assert_array_equal(back.point_ids, snapshot.point_ids)
    np.testing.assert_array_equal(back.p_world, snapshot.p_world)
    for name in ("keyframe_ids", "stamps_ns", "T_world_cam"):
        np.testing.assert_array_equal(getattr(back.keyframes, name), getattr(snapshot.keyframes, name))
    trajectory = codec.decode_keyframe_trajectory(codec.encode_keyframe_trajectory(node.trajectory()))
    assert (trajectory.keyframes_processed, trajectory.finished) == (3, False)
    empty = codec.decode_keyframe_trajectory(codec.encode_keyframe_trajectory(_node().trajectory()))
    assert empty.T_world_cam.shape == (0, 4, 4)


def test_mismatched_replies_are_refused():
    bad = codec.KeyframeTrajectoryMessage(np.arange(2), np.arange(3), np.zeros((2, 4, 4)))
    with pytest.raises(MessageError, match="do not agree"):
        codec.encode_keyframe_trajectory(bad)
    good = codec.KeyframeTrajectoryMessage(np.arange(2), np.arange(2), np.zeros((2, 4, 4)))
    with pytest.raises(MessageError, match="3 point positions for 2 point ids"):
        codec.encode_map_snapshot(codec.MapSnapshotMessage(good, np.arange(2), np.zeros((3, 3))))


def test_status_carries_per_step_timings():
    status = codec.StageStatusMessage("backend", "running", 7, 12.5, 3, timings_ms={"local_ba": 9.0, "total": 12.5})
    assert codec.decode_stage_status(codec.encode_stage_status(status)) == status


class SlowNode(BackendNode):
    """A backend whose steps take ``delay_s`` seconds: the frontend outpaces it."""

    def __init__(self, delay_s: float):
        super().__init__(LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), IdentityAdjuster()))
        self.delay_s = delay_s

    def step(self, keyframe, queued=0):
        time.sleep(self.delay_s)
        return super().step(keyframe, queued)


class GatedNode(BackendNode):
    """A backend that holds its first keyframe until ``gate`` opens, and notes each step's backlog."""

    def __init__(self):
        super().__init__(LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), IdentityAdjuster()))
        self.gate = threading.Event()
        self.queued: list[int] = []
        self.deferred: list[int] = []

    def step(self, keyframe, queued=0):
        assert self.gate.wait(timeout=20.0)
        self.queued.append(queued)
        update = super().step(keyframe, queued)
        self.deferred.append(self.mapper.last_stats.deferred)
        return update


def test_a_backlog_defers_local_mapping_but_the_last_keyframe_gets_it_before_the_end():
    """Keyframes queued behind the current one defer fusion, local BA and keyframe culling; the end
    of stream waiting behind the last keyframe is no backlog: it gets full local mapping, and every
    keyframe still gets its own update, before the end of stream."""
    n, session_name = 6, "backend-backlog-test"
    hub_endpoint = bus.free_tcp_endpoint()
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub, bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
        updates = bus.subscribe(hub, keys.backend_map_update(session_name), codec.decode_map_update, "lossless", 64)
        publisher = bus.declare_publisher(hub, keys.frontend_keyframe(session_name), codec.KEYFRAME, "lossless")
        node, stop, result, world = GatedNode(), threading.Event(), {}, World()
        config = BackendConfig(keyframe_queue=16, linger_s=0.0)
        worker = threading.Thread(target=lambda: result.setdefault("ended", serve(peer, session_name, node, config, stop.is_set)))
        worker.start()
        try:
            assert bus.wait_for_alive(hub, session_name, ["backend"], timeout_s=10.0) == set()
            assert bus.wait_for_subscribers(publisher, timeout_s=10.0)
            # A second subscriber in the backend's session: once it has the end of stream, so has the inbox.
            arrived = threading.Event()
            watcher = peer.declare_subscriber(
                keys.frontend_keyframe(session_name),
                lambda sample: isinstance(codec.decode_keyframe(sample.payload.to_bytes()), codec.EndOfStream) and arrived.set(),
            )
            for k in range(n):
                publisher.put(codec.encode_keyframe(world.keyframe(k)))
            publisher.put(codec.encode_end_of_stream(codec.KEYFRAME, n))
            assert arrived.wait(timeout=20.0), "the keyframes did not arrive"  # all in the inbox, the first one held
            watcher.undeclare()
            node.gate.set()
            received = [updates.get(timeout_s=10.0) for _ in range(n + 1)]
            worker.join(timeout=10.0)
        finally:
            stop.set()
            worker.join(timeout=10.0)
        assert result["ended"] is True
        # The first keyframe's backlog was counted as it arrived; from the second on, all were waiting.
        assert node.queued[1:] == list(range(n - 2, -1, -1))
        assert node.deferred[1:] == [1] * (n - 2) + [0]
        assert [u.keyframe_id for u in received[:n]] == list(range(n))
        assert received[n] == codec.EndOfStream(n)
        updates.close()


def test_serve_maps_every_keyframe_answers_queries_and_forwards_the_end():
    """A burst of keyframes into a 2-keyframe inbox: none is dropped, each gets its update in order,
    statuses report queue depth and timings, queries are answered during the run and after the end."""
    n, session_name = 8, "backend-node-test"
    hub_endpoint = bus.free_tcp_endpoint()
    config = BackendConfig(keyframe_queue=2, linger_s=30.0)
    world = World()
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub, bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
        updates = bus.subscribe(hub, keys.backend_map_update(session_name), codec.decode_map_update, "lossless", 64)
        statuses = bus.subscribe(hub, keys.status(session_name, "backend"), codec.decode_stage_status, "lossless", 64)
        publisher = bus.declare_publisher(hub, keys.frontend_keyframe(session_name), codec.KEYFRAME, "lossless")
        node, stop, result = SlowNode(0.05), threading.Event(), {}
        worker = threading.Thread(target=lambda: result.setdefault("ended", serve(peer, session_name, node, config, stop.is_set)))
        worker.start()
        try:
            assert bus.wait_for_alive(hub, session_name, ["backend"], timeout_s=10.0) == set()
            assert bus.wait_for_subscribers(publisher, timeout_s=10.0)
            for k in range(n):
                publisher.put(codec.encode_keyframe(world.keyframe(k)))  # blocks while the inbox is full
            first = updates.get(timeout_s=10.0)
            during = query_trajectory(hub, session_name, timeout_s=10.0)
            publisher.put(codec.encode_end_of_stream(codec.KEYFRAME, n))
            received = [first] + [updates.get(timeout_s=10.0) for _ in range(n)]
            after = query_map(hub, session_name, timeout_s=10.0)
            assert worker.is_alive()  # lingering to answer queries
        finally:
            stop.set()
            worker.join(timeout=10.0)
        assert result["ended"] is True and not worker.is_alive()
        assert [u.keyframe_id for u in received[:n]] == list(range(n))
        assert received[n] == codec.EndOfStream(n)
        assert during is not None and 1 <= during.keyframes_processed <= n and not during.finished
        ids = during.keyframe_ids.tolist()  # redundant keyframes may have been culled already
        assert ids == sorted(ids) and ids[0] == 0 and ids[-1] == during.keyframes_processed - 1
        assert after is not None and after.keyframes.finished
        assert after.keyframes.keyframe_ids.tolist() == list(node.mapper.map.keyframes)
        assert len(after.point_ids) == len(node.mapper.map.points)
        got = []
        while (status := statuses.get(timeout_s=1.0)) is not None:
            got.append(status)
        running = [s for s in got if s.state == "running"]
        assert [s.processed for s in running] == list(range(1, n + 1))
        assert all(set(s.timings_ms) == set(TIMING_STEPS) and s.step_ms >= 50.0 for s in running)
        assert max(s.queue_depth for s in running) >= 1  # the burst waited in the inbox
        assert got[-1] == codec.StageStatusMessage("backend", "finished", n)  # ("starting" may precede the match)
        for inbox in (updates, statuses):
            inbox.close()


def test_serve_stopped_early_still_ends_the_stream():
    session_name = "backend-stop-test"
    hub_endpoint = bus.free_tcp_endpoint()
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub, bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
        updates = bus.subscribe(hub, keys.backend_map_update(session_name), codec.decode_map_update, "lossless", 8)
        stop, result = threading.Event(), {}
        worker = threading.Thread(target=lambda: result.setdefault("ended", serve(peer, session_name, _node(), BackendConfig(), stop.is_set)))
        worker.start()
        try:
            assert bus.wait_for_alive(hub, session_name, ["backend"], timeout_s=10.0) == set()
        finally:
            stop.set()
            worker.join(timeout=10.0)
        assert result["ended"] is False
        assert updates.get(timeout_s=5.0) == codec.EndOfStream(0)
        updates.close()


@pytest.mark.parametrize("answer_before_local_ba", [False, True])
def test_a_restarted_backend_rebuilds_its_map_from_the_journal_and_answers_what_was_not_answered(tmp_path, answer_before_local_ba):
    """The journal a backend leaves when it dies while mapping keyframe 5 (keyframes 0-4 answered):
    a restarted backend rebuilds the same map, publishes keyframe 5's answer (the one the dead one
    would have published), ignores keyframe 5 sent again by the frontend, and maps keyframe 6 as the
    unharmed backend would. Answered before local BA, each keyframe's answer and correction are
    published again the same way (the correction is what a frontend waiting after the answer needs)."""
    session_name = "backend-restart-test"
    world = World()
    messages = [codec.encode_keyframe(world.keyframe(k)) for k in range(7)]

    def node() -> BackendNode:
        made = _node()
        made.answer_before_local_ba = answer_before_local_ba
        return made

    unharmed = node()
    expected = [unharmed.step(codec.decode_keyframe(m)) for m in messages]
    assert len(expected[5].updates) == (2 if answer_before_local_ba else 1)
    journal = tmp_path / "backend.journal"
    with JournalWriter(journal) as writer:
        for k, message in enumerate(messages[:6]):
            writer.keyframe(message, 0)
            if k < 5:
                writer.answered(k)
    hub_endpoint = bus.free_tcp_endpoint()
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub, bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
        updates = bus.subscribe(hub, keys.backend_map_update(session_name), lambda b: b, "lossless", 64)
        publisher = bus.declare_publisher(hub, keys.frontend_keyframe(session_name), codec.KEYFRAME, "lossless")
        restarted, stop, result = node(), threading.Event(), {}
        worker = threading.Thread(
            target=lambda: result.setdefault("ended", serve(peer, session_name, restarted, BackendConfig(linger_s=0.0), stop.is_set, journal, rebuild=True))
        )
        worker.start()
        try:
            assert bus.wait_for_alive(hub, session_name, ["backend"], timeout_s=10.0) == set()
            assert bus.wait_for_subscribers(publisher, timeout_s=10.0)
            for message in (messages[5], messages[6], codec.encode_end_of_stream(codec.KEYFRAME, 7)):
                publisher.put(message)
            published = [*expected[5].updates, *expected[6].updates]
            received = [updates.get(timeout_s=20.0) for _ in range(len(published) + 1)]
            worker.join(timeout=20.0)
        finally:
            stop.set()
            worker.join(timeout=10.0)
        updates.close()
    assert result["ended"] is True
    assert received[:-1] == [codec.encode_map_update(update) for update in published]
    assert codec.decode_map_update(received[-1]) == codec.EndOfStream(7)
    assert restarted.processed == unharmed.processed == 7
    unharmed.finished = True  # as serve marks it at the end of stream
    assert codec.encode_map_snapshot(restarted.snapshot()) == codec.encode_map_snapshot(unharmed.snapshot())
    entries = read_journal(journal)
    assert [e.keyframe_id for e in entries if isinstance(e, Answered)] == [0, 1, 2, 3, 4, 5, 6]
    assert sum(isinstance(e, JournaledKeyframe) for e in entries) == 7  # keyframe 5 is not journaled twice


def test_only_stereo_and_rgbd_keyframes_are_answered_before_their_local_ba():
    """A monocular keyframe gets one update, its answer after local BA, whatever
    ``answer_before_local_ba`` says: ORB-SLAM's monocular tracking makes no keyframe beside a busy
    local mapping, so answering before the BA would starve a monocular map of keyframes."""
    node = _node()
    node.answer_before_local_ba = True
    stereo = World().keyframe(0)
    assert node.answers_before_local_ba(stereo)
    assert node.answers_before_local_ba(dataclasses.replace(stereo, sensor="rgbd"))
    assert not node.answers_before_local_ba(dataclasses.replace(stereo, sensor="mono"))
    node.answer_before_local_ba = False
    assert not node.answers_before_local_ba(stereo)
    stepped = _node()
    stepped.answer_before_local_ba = True
    assert [u.kind for u in stepped.step(stereo).updates] == ["keyframe", "correction"]
    mono = _node()
    mono.answer_before_local_ba = True
    no_depth = np.full(len(stereo.right_u), -1.0, np.float32)
    updates = mono.step(dataclasses.replace(World().keyframe(0), sensor="mono", right_u=no_depth, depth_m=no_depth)).updates
    assert [u.kind for u in updates] == ["keyframe"] and not updates[0].corrections_after_next_frame


def test_a_keyframe_answered_before_its_local_ba_leaves_the_map_step_leaves():
    """``begin`` then ``finish`` (``backend.answer_before_local_ba``) make the map ``step`` makes, bit
    for bit: the answer carries insertion, new points and fusion and announces one correction after
    it, which carries local BA and keyframe culling; replayed in order they leave what step's one
    update leaves."""
    from zenslam.backend.local_ba import LocalBAConfig
    from zenslam.backend.local_mapping import bundle_adjuster

    def node() -> BackendNode:
        config = LocalMappingConfig()
        return BackendNode(LocalMapper(new_backend_map(config), config, bundle_adjuster(LocalBAConfig())))

    rng = np.random.default_rng(3)
    world_a, world_b, world_c = World(), World(), World()
    whole, halves, stepped = node(), node(), node()
    stepped.answer_before_local_ba = True  # its step is begin then finish: the worker's messages
    for k in range(8):
        noise = make_T(np.eye(3), rng.normal(0.0, 0.02, 3))  # BA has something to correct
        kf_a, kf_b, kf_c = (w.keyframe(k) for w in (world_a, world_b, world_c))  # a World's keyframe k only once
        kf_a, kf_b, kf_c = (dataclasses.replace(kf, T_world_cam=noise @ kf.T_world_cam) for kf in (kf_a, kf_b, kf_c))
        merged = whole.step(kf_a).updates
        answer = halves.begin(kf_b).updates
        corrections = halves.finish().updates
        assert [codec.encode_map_update(u) for u in stepped.step(kf_c).updates] == [
            codec.encode_map_update(u) for u in (*answer, *corrections)
        ]
        assert len(merged) == 1 and merged[0].answers_keyframe and not merged[0].corrections_after_next_frame
        assert len(answer) == 1 and answer[0].answers_keyframe and answer[0].keyframe_id == k
        assert answer[0].corrections_following == 1 and answer[0].corrections_after_next_frame
        assert [(u.kind, u.keyframe_id, u.corrections_following) for u in corrections] == [("correction", k, 0)]
        assert whole.last_timings_ms.keys() == halves.last_timings_ms.keys()
    moved = [c.id for c in corrections[0].keyframes]
    assert moved, "local BA moved no keyframe: the test would not see a correction"
    assert sorted(whole.map.keyframes) == sorted(halves.map.keyframes)
    for kf_id in whole.map.keyframes:
        assert np.array_equal(whole.map.keyframe(kf_id).T_world_cam, halves.map.keyframe(kf_id).T_world_cam)
    ids = sorted(whole.map.points)
    assert ids == sorted(halves.map.points)
    assert np.array_equal(whole.map.positions(np.array(ids)), halves.map.positions(np.array(ids)))
    with pytest.raises(RuntimeError, match="without a keyframe begun"):
        halves.finish()


def test_a_global_ba_refines_the_whole_map_before_it_is_saved(tmp_path):
    """backend.global_ba_before_save: the map a localisation run will rely on gets one global BA at the end
    of the run and its correction is published before the map is written; off, the map is written as is."""
    from test_global_ba import perturbed_map  # noqa: E402  (tests/backend is on the path under pytest)

    from zenslam.backend.global_ba import GlobalBAConfig
    from zenslam.backend.global_ba_runner import GlobalBARunner
    from zenslam.backend.local_mapping import BAWindowConfig
    from zenslam.backend.node import _save_map

    class Recorded:
        def __init__(self):
            self.update = self
            self.sent: list[bytes] = []

        def put(self, payload: bytes) -> None:
            self.sent.append(payload)

    for enabled in (True, False):
        bmap, _, _ = perturbed_map()
        runner = GlobalBARunner(bmap, GlobalBAConfig(), BAWindowConfig(), in_background=False)
        node = BackendNode(LocalMapper(bmap, LocalMappingConfig(), IdentityAdjuster()), global_ba=runner)
        node._newest = (max(bmap.keyframes), 0)  # as after mapping the last keyframe
        written: list[tuple[str, np.ndarray]] = []
        node.save_map = lambda path, node=node: written.append((path, np.stack([p.p_world for p in node.map.points.values()])))
        before = np.stack([p.p_world for p in bmap.points.values()])
        outputs = Recorded()
        config = dataclasses.replace(BackendConfig(), save_map=str(tmp_path / "map.zmap"), global_ba_before_save=enabled)
        _save_map(outputs, node, config, finish_global_ba=True)
        assert [path for path, _ in written] == [config.save_map]
        assert runner.applied == int(enabled) and len(outputs.sent) == int(enabled)
        if enabled:
            assert codec.decode_map_update(outputs.sent[0]).kind == "correction"
            assert not np.array_equal(written[0][1], before)  # the saved points are the refined ones
        else:
            np.testing.assert_array_equal(written[0][1], before)
    assert BackendNode(LocalMapper(new_backend_map(LocalMappingConfig()), LocalMappingConfig(), IdentityAdjuster())).global_ba_before_save() is None
    bmap, _, _ = perturbed_map()  # loaded and saved again without a keyframe mapped: written as it was
    runner = GlobalBARunner(bmap, GlobalBAConfig(), BAWindowConfig(), in_background=False)
    assert BackendNode(LocalMapper(bmap, LocalMappingConfig(), IdentityAdjuster()), global_ba=runner).global_ba_before_save() is None
    assert runner.runs == 0
