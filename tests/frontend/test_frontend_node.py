"""The frontend node with a stand-in tracker: what it sends per frame, and a lockstep exchange with the source over the bus."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError
from zenslam.frontend.node import FrontendNode, serve
from zenslam.geometry import make_T
from zenslam.schemas import codec, keys
from zenslam.runtime import bus
from zenslam.service.run_config import SourceConfig
from zenslam.service.source_node import play
from zenslam.service.sources.frame import SensorFrame

CAL = PinholeCalibration(fx=100.0, fy=100.0, cx=16.0, cy=12.0, width=32, height=24, baseline_m=0.1)


def _keyframe(index: int, stamp_ns: int, n: int = 5) -> SimpleNamespace:
    return SimpleNamespace(
        id=index // 2, frame_index=index, stamp_ns=stamp_ns, T_world_cam=make_T(np.eye(3), [index, 0, 0]),
        px=np.full((n, 2), 3.0, np.float32), level=np.zeros(n, np.int16), angle_deg=np.zeros(n, np.float32),
        descriptors=np.zeros((n, 32), np.uint8), right_u=np.full(n, -1, np.float32), depth_m=np.ones(n, np.float32),
        map_point_ids=np.arange(n, dtype=np.int64), features=SimpleNamespace(scale_factors=1.2 ** np.arange(8)),
        new_point_ids=np.arange(2, dtype=np.int64), new_points_world=np.zeros((2, 3)),
    )


class StubPipeline:
    """Tracks every frame: a keyframe on even frames, lost on every frame whose index ends in 7."""

    may_ask_backend = False  # a lost stub frame asks nobody

    @property
    def map_sync(self) -> SimpleNamespace:
        """Map updates reach the stub's ``apply_map_update``, where a test gives it one."""
        return SimpleNamespace(apply=lambda update: self.apply_map_update(update))

    def __init__(self, calibration: PinholeCalibration, sensor: str):
        self.calibration, self.sensor, self.seen, self.in_flight = calibration, sensor, [], []
        self.prepared, self.used_prepared = [], []

    def prepare(self, index, stamp_ns, left, right=None, depth_m=None):
        self.prepared.append(index)
        return SimpleNamespace(index=index)

    def step(self, index, stamp_ns, left, right=None, depth_m=None, keyframes_in_flight=0, prepared=None, candidates=None):
        assert left.shape == (24, 32) and right is not None and depth_m is None
        assert prepared is None or prepared.index == index
        self.used_prepared.append(prepared is not None)
        self.seen.append(index)
        self.in_flight.append(keyframes_in_flight)
        lost = index % 10 == 7
        keyframe = None if lost or index % 2 else _keyframe(index, stamp_ns)
        return SimpleNamespace(
            index=index, stamp_ns=stamp_ns, state="lost" if lost else "ok", lost_reason="stub says lost" if lost else None,
            T_world_cam=None if lost else make_T(np.eye(3), [index * 0.1, 0, 0]), n_tracked=0 if lost else 100 + index,
            keyframe=keyframe, keyframes_made=() if keyframe is None else (keyframe,),
            timings_ms={"extraction": 1.0, "total": 2.0 + index},
            reference_keyframe_id=-1 if lost else index // 2, T_reference_cam=None if lost else make_T(np.eye(3), [0, 0, index]),
            relocalised=False,
        )


def _frames(n: int) -> list[SensorFrame]:
    rng = np.random.default_rng(0)
    return [
        SensorFrame(i, 1_000_000 * i, rng.integers(0, 256, (24, 32), dtype=np.uint8), rng.integers(0, 256, (24, 32), dtype=np.uint8))
        for i in range(n)
    ]


def _message(frame: SensorFrame, calibration: PinholeCalibration = CAL) -> codec.FrameMessage:
    return codec.decode_sensor_frame(codec.encode_sensor_frame(frame, calibration, "stereo"))


def test_handle_encodes_pose_state_and_keyframe():
    pipelines = []
    node = FrontendNode(lambda cal, sensor: pipelines.append(StubPipeline(cal, sensor)) or pipelines[-1])
    frames = _frames(8)
    out0 = node.handle(_message(frames[0]))
    assert pipelines[0].calibration == CAL and pipelines[0].sensor == "stereo"
    state = codec.decode_tracking_state(out0.state)
    assert (state.index, state.state, state.n_tracked, state.has_pose, state.keyframe_id) == (0, "ok", 100, True, 0)
    assert state.reference_keyframe_id == 0 and np.allclose(state.T_reference_cam, np.eye(4))
    assert state.timings_ms == {"extraction": 1.0, "total": 2.0}
    (kf_bytes,) = out0.keyframes
    kf = codec.decode_keyframe(kf_bytes)
    assert (kf.id, kf.frame_index, len(kf.keypoints_px), len(kf.new_point_ids)) == (0, 0, 5, 2)
    np.testing.assert_allclose(kf.scale_factors, 1.2 ** np.arange(8))
    assert codec.decode_pose_in_frame(out0.pose).frame_id == "world"
    for frame in frames[1:]:
        out = node.handle(_message(frame))
    lost = codec.decode_tracking_state(out.state)
    assert (lost.index, lost.state, lost.lost_reason, lost.has_pose) == (7, "lost", "stub says lost", False)
    assert lost.reference_keyframe_id == -1 and lost.T_reference_cam is None
    assert out.pose is None and out.keyframes == ()
    assert len(pipelines) == 1 and node.frames == 8 and node.keyframes == 4


def test_keyframes_in_flight_reach_the_pipeline():
    """Sent keyframes count as in flight until their map update is applied (the keyframe decision's
    view of local mapping); without the backend's updates nothing is ever in flight."""
    pipelines = []
    node = FrontendNode(lambda cal, sensor: pipelines.append(StubPipeline(cal, sensor)) or pipelines[-1])
    node.tracks_backend = True
    frames = _frames(5)
    for frame in frames[:3]:  # keyframes at frames 0 and 2
        node.handle(_message(frame))
    assert pipelines[0].in_flight == [0, 1, 1] and node.keyframes_in_flight == 2
    pipelines[0].apply_map_update = lambda update: None
    node.apply_map_update(SimpleNamespace(keyframe_id=0, answers_keyframe=True))
    node.handle(_message(frames[3]))
    assert pipelines[0].in_flight[-1] == 1
    # A correction (a loop's, a global BA's) answers no keyframe: keyframe 2 is still in flight, and
    # once answered nothing is (before, a correction counted as an answer and left -1 in flight
    # after it, so local mapping never looked idle to the keyframe decision again).
    node.apply_map_update(SimpleNamespace(keyframe_id=0, answers_keyframe=False))
    assert node.keyframes_in_flight == 1
    node.apply_map_update(SimpleNamespace(keyframe_id=2, answers_keyframe=True))
    assert node.keyframes_in_flight == 0
    node.handle(_message(frames[4]))  # decided with local mapping idle; makes keyframe 4
    assert pipelines[0].in_flight[-1] == 0 and node.keyframes_in_flight == 1
    alone = FrontendNode(lambda cal, sensor: StubPipeline(cal, sensor))
    for frame in frames:
        alone.handle(_message(frame))
    assert alone.keyframes == 3 and alone.keyframes_in_flight == 0


def test_a_frame_prepared_ahead_is_used_by_its_own_handle_only():
    pipelines = []
    node = FrontendNode(lambda cal, sensor: pipelines.append(StubPipeline(cal, sensor)) or pipelines[-1])
    frames = _frames(4)
    node.prepare_ahead(_message(frames[0]))  # no pipeline before the first frame: nothing to prepare with
    node.handle(_message(frames[0]))
    node.prepare_ahead(_message(frames[1]))
    node.handle(_message(frames[1]))
    node.prepare_ahead(_message(frames[3]))  # frame 2 comes first: the frame prepared for 3 is not used for it
    node.handle(_message(frames[2]))
    node.handle(_message(frames[3]))
    node.close()
    assert pipelines[0].prepared[0] == 1  # (whether 3's ran before it was dropped is up to the thread)
    assert pipelines[0].used_prepared == [False, True, False, False]
    assert node.built_ahead == 1  # the count the node logs at the end of a lockstep stream


def test_gaps_in_frame_indices_count_as_skipped():
    node = FrontendNode(StubPipeline)
    frames = _frames(6)
    for i in (0, 1, 4, 5):
        node.handle(_message(frames[i]))
    assert node.skipped == 2


def test_a_camera_change_mid_run_is_refused():
    node = FrontendNode(StubPipeline)
    frames = _frames(2)
    node.handle(_message(frames[0]))
    other = PinholeCalibration(fx=101.0, fy=100.0, cx=16.0, cy=12.0, width=32, height=24, baseline_m=0.1)
    with pytest.raises(CalibrationError, match="one run tracks one camera"):
        node.handle(_message(frames[1], other))


def test_lockstep_source_and_frontend_over_the_bus():
    """Every frame is tracked in order, every announced pose arrives, and both streams end."""
    n, session_name = 25, "node-test"
    hub_endpoint = bus.free_tcp_endpoint()
    config = bus.BusConfig()
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub, bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
        states = bus.subscribe(hub, keys.frontend_state(session_name), codec.decode_tracking_state, "lossless", 64)
        poses = bus.subscribe(hub, keys.frontend_pose(session_name), codec.decode_pose_in_frame, "lossless", 64)
        keyframes = bus.subscribe(hub, keys.frontend_keyframe(session_name), codec.decode_keyframe, "lossless", 64)
        node = FrontendNode(StubPipeline)
        stop = threading.Event()
        result = {}
        frontend = threading.Thread(target=lambda: result.setdefault("ended", serve(peer, session_name, node, "lockstep", config, stop.is_set)))
        frontend.start()
        try:
            assert bus.wait_for_alive(hub, session_name, ["frontend"], timeout_s=10.0) == set()
            source_config = SourceConfig(answer_timeout_s=10.0)
            sent = play(hub, session_name, _frames(n), CAL, "stereo", source_config, lambda: False, "stub", start_timeout_s=10.0)
            frontend.join(timeout=10.0)
        finally:
            stop.set()
            frontend.join(timeout=10.0)
        assert sent == n and result["ended"] is True
        received = [states.get(timeout_s=2.0) for _ in range(n + 1)]
        assert [s.index for s in received[:n]] == list(range(n))
        assert received[n] == codec.EndOfStream(n)
        got_poses = [poses.get(timeout_s=2.0) for _ in range(sum(s.has_pose for s in received[:n]))]
        assert [p.stamp_ns for p in got_poses] == [s.stamp_ns for s in received[:n] if s.has_pose]
        got_keyframes = []
        while not isinstance(message := keyframes.get(timeout_s=2.0), codec.EndOfStream):
            got_keyframes.append(message.frame_index)
        assert got_keyframes == [i for i in range(n) if i % 2 == 0 and i % 10 != 7]
        assert message == codec.EndOfStream(len(got_keyframes))
        for inbox in (states, poses, keyframes):
            inbox.close()


class _MappedStub(StubPipeline):
    def apply_map_update(self, update) -> None:
        pass


def test_a_backend_that_ends_its_stream_ends_the_lockstep_frontends_without_error():
    """The backend was stopped while the frontend waited for its update of keyframe 1: the frontend
    ends its own streams (the source then stops), and its last status says it stopped early."""
    from zenslam.frontend.config import FrontendConfig
    from zenslam.schemas.map_update import MapUpdate

    session_name = "backend-stopped"
    with bus.open_session(bus.BusConfig()) as session:
        frames = bus.declare_publisher(session, keys.sensor_frame(session_name), codec.SENSOR_FRAME, "lossless")
        updates = bus.declare_publisher(session, keys.backend_map_update(session_name), codec.MAP_UPDATE, "lossless")
        keyframes = bus.subscribe(session, keys.frontend_keyframe(session_name), codec.decode_keyframe, "lossless", 64)
        states = bus.subscribe(session, keys.frontend_state(session_name), codec.decode_tracking_state, "lossless", 64)
        statuses = bus.subscribe(session, keys.status(session_name, "frontend"), codec.decode_stage_status, "lossless", 64)
        result = {}
        node = FrontendNode(_MappedStub)
        config = FrontendConfig(update_timeout_s=30.0)
        frontend = threading.Thread(target=lambda: result.setdefault(
            "ended", serve(session, session_name, node, "lockstep", bus.BusConfig(), lambda: False, map_updates=config)))
        frontend.start()
        assert bus.wait_for_alive(session, session_name, ["frontend"], timeout_s=10.0) == set()
        for frame in _frames(6):
            frames.put(codec.encode_sensor_frame(frame, CAL, "stereo"))
        assert keyframes.get(timeout_s=10.0).id == 0  # frame 0: answered
        updates.put(codec.encode_map_update(MapUpdate(keyframe_id=0, stamp_ns=0)))
        assert keyframes.get(timeout_s=10.0).id == 1  # frame 2: the backend stops instead of answering
        updates.put(codec.encode_end_of_stream(codec.MAP_UPDATE, 1))
        frontend.join(timeout=10.0)
        assert not frontend.is_alive() and result["ended"] is False
        received = []
        while not isinstance(state := states.get(timeout_s=5.0), codec.EndOfStream):
            assert state is not None, "the frontend did not end its stream"
            received.append(state.index)
        assert received == [0, 1, 2] and state == codec.EndOfStream(3)
        last = [s for s in iter(lambda: statuses.get(timeout_s=1.0), None)][-1]
        assert last.state == "finished" and last.detail == "stopped"
        for inbox in (keyframes, states, statuses):
            inbox.close()


def test_serve_refuses_frames_of_another_camera_or_not_after_the_last():
    node = FrontendNode(StubPipeline)
    frames = _frames(3)
    node.handle(_message(frames[1]))
    other = PinholeCalibration(fx=101.0, fy=100.0, cx=16.0, cy=12.0, width=32, height=24, baseline_m=0.1)
    assert "another camera" in node.refusal(_message(frames[2], other))
    assert "is not after frame 1" in node.refusal(_message(frames[0]))
    assert "is not after frame 1" in node.refusal(_message(frames[1]))
    assert node.refusal(_message(frames[2])) is None


def test_a_frame_sent_again_is_refused_and_answered_with_the_newest_state():
    """A restarted source resumes after the newest frame the hub saw tracked, which can be older than
    the frontend's: the frames it sends again are not tracked twice, but each is answered (with the
    newest state) so that the source, waiting for a state at or past it, goes on."""
    session_name = "sent-again"
    with bus.open_session(bus.BusConfig()) as session:
        frames = bus.declare_publisher(session, keys.sensor_frame(session_name), codec.SENSOR_FRAME, "lossless")
        states = bus.subscribe(session, keys.frontend_state(session_name), codec.decode_tracking_state, "lossless", 64)
        node = FrontendNode(StubPipeline)
        stop = threading.Event()
        frontend = threading.Thread(target=lambda: serve(session, session_name, node, "lockstep", bus.BusConfig(), stop.is_set))
        frontend.start()
        try:
            assert bus.wait_for_alive(session, session_name, ["frontend"], timeout_s=10.0) == set()
            sequence = _frames(5)
            for frame in (*sequence[:4], sequence[2], sequence[3], sequence[4]):
                frames.put(codec.encode_sensor_frame(frame, CAL, "stereo"))
            received = [states.get(timeout_s=10.0) for _ in range(7)]
        finally:
            stop.set()
            frontend.join(timeout=10.0)
            states.close()
    assert [state.index for state in received] == [0, 1, 2, 3, 3, 3, 4]
    assert (received[4].stamp_ns, received[5].stamp_ns) == (received[3].stamp_ns,) * 2
    assert node._pipeline.seen == [0, 1, 2, 3, 4] and node.refused == 2  # none tracked twice


def test_a_restarted_frontend_applies_no_answer_to_its_predecessors_keyframes():
    """Keyframe ids below the frontend's first (``entering_map``: past the backend's map) were its
    predecessor's: their answers are not applied, corrections and answers to its own keyframes are."""
    from zenslam.frontend.config import FrontendConfig, entering_map
    from zenslam.frontend.map_update_inbox import MapUpdateInbox
    from zenslam.schemas.map_update import MapUpdate

    applied: list[MapUpdate] = []
    node = SimpleNamespace(apply_map_update=applied.append)
    config = entering_map(FrontendConfig(), next_keyframe_id=40, next_point_id=9000)
    assert config.tracking.start_in_map and config.tracking.local_map.point_id_start == 9000
    with bus.open_session(bus.BusConfig()) as session:
        updates = MapUpdateInbox(session, "restarted-frontend", config, resend=lambda message: None)
        try:
            predecessors = MapUpdate(keyframe_id=39, stamp_ns=0)
            correction = MapUpdate(keyframe_id=39, stamp_ns=0, kind="correction")
            own = MapUpdate(keyframe_id=40, stamp_ns=1)
            for update in (predecessors, correction, own):
                updates._apply(node, update)
        finally:
            updates.close()
    assert applied == [correction, own]


class _LoggedStub(StubPipeline):
    """Logs each frame tracked and each map update applied, in order, to ``log``."""

    log: list[tuple] = []

    def step(self, index, *args, **kwargs):
        self.log.append(("frame", index, kwargs.get("keyframes_in_flight")))
        return super().step(index, *args, **kwargs)

    def apply_map_update(self, update) -> None:
        self.log.append((update.kind, update.keyframe_id))


def test_an_answer_before_local_ba_lets_one_frame_be_tracked_before_its_correction():
    """Lockstep with ``backend.answer_before_local_ba``: the frame after a keyframe is tracked on its
    answer, with local mapping busy (the BA runs); the frame after that waits for the correction
    and the loop correction it announces, whenever they come, so the run is the same every time."""
    from zenslam.frontend.config import FrontendConfig
    from zenslam.schemas.map_update import MapUpdate

    session_name, log = "answer-before-ba", []
    _LoggedStub.log = log
    with bus.open_session(bus.BusConfig()) as session:
        frames = bus.declare_publisher(session, keys.sensor_frame(session_name), codec.SENSOR_FRAME, "lossless")
        updates = bus.declare_publisher(session, keys.backend_map_update(session_name), codec.MAP_UPDATE, "lossless")
        keyframes = bus.subscribe(session, keys.frontend_keyframe(session_name), codec.decode_keyframe, "lossless", 64)
        states = bus.subscribe(session, keys.frontend_state(session_name), codec.decode_tracking_state, "lossless", 64)
        result = {}
        config = FrontendConfig(update_timeout_s=30.0)
        frontend = threading.Thread(target=lambda: result.setdefault(
            "ended", serve(session, session_name, FrontendNode(_LoggedStub), "lockstep", bus.BusConfig(), lambda: False, map_updates=config)))
        frontend.start()
        assert bus.wait_for_alive(session, session_name, ["frontend"], timeout_s=10.0) == set()
        for frame in _frames(5):
            frames.put(codec.encode_sensor_frame(frame, CAL, "stereo"))
        frames.put(codec.encode_end_of_stream(codec.SENSOR_FRAME, 5))
        assert keyframes.get(timeout_s=10.0).id == 0  # frame 0
        updates.put(codec.encode_map_update(MapUpdate(keyframe_id=0, stamp_ns=0, corrections_following=1, corrections_after_next_frame=True)))
        assert [states.get(timeout_s=10.0).index for _ in range(2)] == [0, 1]  # frame 1 on the answer alone
        assert states.get(timeout_s=0.5) is None  # frame 2 waits for keyframe 0's corrections
        updates.put(codec.encode_map_update(MapUpdate(keyframe_id=0, stamp_ns=0, kind="correction", corrections_following=1)))
        assert states.get(timeout_s=0.5) is None  # and for the loop correction the BA's announces
        updates.put(codec.encode_map_update(MapUpdate(keyframe_id=0, stamp_ns=0, kind="correction")))
        assert states.get(timeout_s=10.0).index == 2
        assert keyframes.get(timeout_s=10.0).id == 1  # frame 2; answered the old way, corrections before the next frame
        updates.put(codec.encode_map_update(MapUpdate(keyframe_id=1, stamp_ns=0, corrections_following=1)))
        assert states.get(timeout_s=0.5) is None
        updates.put(codec.encode_map_update(MapUpdate(keyframe_id=1, stamp_ns=0, kind="correction")))
        assert [states.get(timeout_s=10.0).index for _ in range(2)] == [3, 4]
        assert keyframes.get(timeout_s=10.0).id == 2  # frame 4; its corrections are waited for before the end
        updates.put(codec.encode_map_update(MapUpdate(keyframe_id=2, stamp_ns=0, corrections_following=1, corrections_after_next_frame=True)))
        updates.put(codec.encode_map_update(MapUpdate(keyframe_id=2, stamp_ns=0, kind="correction")))
        frontend.join(timeout=10.0)
        assert not frontend.is_alive() and result["ended"] is True
        for inbox in (keyframes, states):
            inbox.close()
    assert log == [
        ("frame", 0, 0), ("keyframe", 0), ("frame", 1, 1), ("correction", 0), ("correction", 0),
        ("frame", 2, 0), ("keyframe", 1), ("correction", 1), ("frame", 3, 0),
        ("frame", 4, 0), ("keyframe", 2), ("correction", 2),
    ]


class _LaggedStub(_LoggedStub):
    """``_LoggedStub`` that may ask the backend where it is after a lost frame (as the tracker does)."""

    def __init__(self, calibration: PinholeCalibration, sensor: str):
        super().__init__(calibration, sensor)
        self.may_ask_backend = False

    def step(self, index, *args, **kwargs):
        out = super().step(index, *args, **kwargs)
        self.may_ask_backend = out.state == "lost"
        return out


def test_lockstep_lag_frames_apply_each_answer_at_its_frame_whatever_its_arrival():
    """``frontend.lockstep_lag_frames: 3``: a keyframe made at frame f is answered before frame f + 3,
    not before, even when its answer is already in the inbox, and not later; a frame after a lost
    one (it may ask the backend where it is) first applies every answer to come, as does the end."""
    from zenslam.frontend.config import FrontendConfig
    from zenslam.schemas.map_update import MapUpdate

    session_name, log = "lag-frames", []
    _LaggedStub.log = log
    with bus.open_session(bus.BusConfig()) as session:
        frames = bus.declare_publisher(session, keys.sensor_frame(session_name), codec.SENSOR_FRAME, "lossless")
        updates = bus.declare_publisher(session, keys.backend_map_update(session_name), codec.MAP_UPDATE, "lossless")
        keyframes = bus.subscribe(session, keys.frontend_keyframe(session_name), codec.decode_keyframe, "lossless", 64)
        result = {}
        config = FrontendConfig(update_timeout_s=30.0, lockstep_lag_frames=3)
        frontend = threading.Thread(target=lambda: result.setdefault(
            "ended", serve(session, session_name, FrontendNode(_LaggedStub), "lockstep", bus.BusConfig(), lambda: False, map_updates=config)))
        frontend.start()
        assert bus.wait_for_alive(session, session_name, ["frontend"], timeout_s=10.0) == set()
        sent = _frames(10)
        frames.put(codec.encode_sensor_frame(sent[0], CAL, "stereo"))
        assert keyframes.get(timeout_s=10.0).id == 0
        # Keyframe 0's answer reaches the frontend before frames 1 and 2: it still waits for frame 3.
        updates.put(codec.encode_map_update(MapUpdate(keyframe_id=0, stamp_ns=0)))
        for frame in sent[1:]:
            frames.put(codec.encode_sensor_frame(frame, CAL, "stereo"))
        frames.put(codec.encode_end_of_stream(codec.SENSOR_FRAME, len(sent)))
        for keyframe_id in range(1, 5):  # made at frames 2, 4, 6 and 8; answered as soon as they come
            assert keyframes.get(timeout_s=10.0).id == keyframe_id
            updates.put(codec.encode_map_update(MapUpdate(keyframe_id=keyframe_id, stamp_ns=0)))
        frontend.join(timeout=10.0)
        assert not frontend.is_alive() and result["ended"] is True
        keyframes.close()
    assert log == [
        ("frame", 0, 0), ("frame", 1, 1), ("frame", 2, 1), ("keyframe", 0),
        ("frame", 3, 1), ("frame", 4, 1), ("keyframe", 1),
        ("frame", 5, 1), ("frame", 6, 1), ("keyframe", 2),
        ("frame", 7, 1), ("keyframe", 3),  # frame 7 is lost: frame 8 may ask the backend, so first every answer
        ("frame", 8, 0), ("frame", 9, 1), ("keyframe", 4),
    ]


def test_a_lockstep_lag_below_one_frame_is_refused():
    from zenslam.errors import ConfigError
    from zenslam.frontend.config import FrontendConfig

    with pytest.raises(ConfigError, match="lockstep_lag_frames=0"):
        FrontendConfig(lockstep_lag_frames=0)
