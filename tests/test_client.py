"""zenslam.client against a stand-in for a run: a zenoh session in this process publishing and answering as the stages do."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import zenoh

from zenslam.camera import PinholeCalibration
from zenslam.client import Client, ClientError, Pose, TrackingState
from zenslam.runtime import bus
from zenslam.runtime.session_file import SessionInfo, write_session_file
from zenslam.schemas import codec, keys
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.schemas.sensor_data import SensorFrame

SESSION = "client-test"


@pytest.fixture
def hub() -> Iterator[tuple[zenoh.Session, str]]:
    """A peer session listening on a free loopback port, standing in for a run's hub and stages."""
    endpoint = bus.free_tcp_endpoint()
    with bus.open_session(bus.BusConfig(listen=(endpoint,))) as session:
        yield session, endpoint


def _pose(k: int) -> codec.StampedPose:
    T = np.eye(4)
    T[:3, 3] = (0.1 * k, 0.0, 0.0)
    return codec.StampedPose(1_000 + k, T)


def _state(k: int, has_pose: bool) -> codec.TrackingStateMessage:
    return codec.TrackingStateMessage(k, 1_000 + k, "ok" if has_pose else "lost", has_pose=has_pose)


def _publish_run(session: zenoh.Session, frames: int) -> None:
    """What the frontend and backend send for ``frames`` frames (every other one tracked), then their ends of stream."""
    states = bus.declare_publisher(session, keys.frontend_state(SESSION), codec.TRACKING_STATE, "lossless")
    poses = bus.declare_publisher(session, keys.frontend_pose(SESSION), codec.POSE_IN_FRAME, "lossless")
    updates = bus.declare_publisher(session, keys.backend_map_update(SESSION), codec.MAP_UPDATE, "lossless")
    for k in range(frames):
        states.put(codec.encode_tracking_state(_state(k, has_pose=k % 2 == 0)))
        if k % 2 == 0:
            poses.put(codec.encode_pose_in_frame(_pose(k)))
    updates.put(codec.encode_map_update(MapUpdate(keyframe_id=0, stamp_ns=1_000, keyframes=(KeyframeCorrection(0, np.eye(4), np.array([-1, 5])),))))
    states.put(codec.encode_end_of_stream(codec.TRACKING_STATE, frames))
    updates.put(codec.encode_end_of_stream(codec.MAP_UPDATE, 1))


def test_callbacks_get_every_message_decoded_and_in_order(hub):
    session, endpoint = hub
    poses: list[Pose] = []
    states: list[TrackingState] = []
    updates: list[MapUpdate] = []
    with Client(SESSION, connect=[endpoint], name="tester") as client:
        client.on_pose(poses.append)
        client.on_state(states.append)
        client.on_map_update(updates.append)
        client.announce()
        assert not bus.wait_for_alive(session, SESSION, ["tester"], timeout_s=30.0)
        _publish_run(session, frames=20)
        end = client.wait_for_end(timeout_s=30.0)
    assert (end.frames, end.poses, end.map_updates, end.tracking_ended, end.mapping_ended) == (20, 10, 1, True, True)
    assert [s.index for s in states] == list(range(20))
    assert [p.stamp_ns for p in poses] == [1_000 + k for k in range(0, 20, 2)]
    np.testing.assert_array_equal(poses[3].T_world_cam, _pose(6).T_world_cam)
    assert isinstance(updates[0], MapUpdate) and updates[0].keyframe_id == 0


def test_a_failing_callback_is_raised_by_wait_for_end(hub):
    session, endpoint = hub
    with Client(SESSION, connect=[endpoint], name="tester") as client:
        client.on_pose(lambda pose: 1 / 0)
        client.announce()
        assert not bus.wait_for_alive(session, SESSION, ["tester"], timeout_s=30.0)
        _publish_run(session, frames=4)
        with pytest.raises(ClientError, match="ZeroDivisionError"):
            client.wait_for_end(timeout_s=30.0)


def test_waits_time_out_with_a_clear_error(hub):
    _, endpoint = hub
    with Client(SESSION, connect=[endpoint]) as client:
        with pytest.raises(ClientError, match="did not end within"):
            client.wait_for_end(timeout_s=0.2)
        with pytest.raises(ClientError, match=r"\['backend'\] .* did not come up"):
            client.wait_for("backend", timeout_s=0.2)


def test_queries_return_the_backends_answer(hub):
    session, endpoint = hub
    answer = codec.KeyframeTrajectoryMessage(np.array([0, 3]), np.array([10, 40]), np.stack([np.eye(4)] * 2), 2, True)

    def reply(query: zenoh.Query) -> None:
        query.reply(query.key_expr, codec.encode_keyframe_trajectory(answer))

    queryable = session.declare_queryable(keys.backend_trajectory_query(SESSION), reply)
    try:
        with Client(SESSION, connect=[endpoint]) as client:
            got = None
            for _ in range(50):  # the queryable's declaration reaches the new client shortly after it joins
                got = client.query_trajectory(timeout_s=1.0)
                if got is not None:
                    break
            assert got is not None and got.finished
            np.testing.assert_array_equal(got.keyframe_ids, [0, 3])
            assert client.query_map(timeout_s=0.2) is None  # no backend/map queryable here
    finally:
        queryable.undeclare()


def test_published_frames_reach_a_frontend_subscription(hub):
    session, endpoint = hub
    inbox = bus.subscribe(session, keys.sensor_frame(SESSION), codec.decode_sensor_frame, "lossless", 8)
    calibration = PinholeCalibration(100.0, 100.0, 15.5, 11.5, 32, 24)
    left = np.arange(32 * 24, dtype=np.uint8).reshape(24, 32)
    with bus.declare_alive(session, SESSION, "frontend"), Client(SESSION, connect=[endpoint]) as client:
        client.wait_for("frontend", timeout_s=30.0)
        client.publish_frame(SensorFrame(0, 5_000, left), calibration, "mono")
        client.end_frames()
        first, second = inbox.get(timeout_s=30.0), inbox.get(timeout_s=30.0)
    inbox.close()
    assert isinstance(first, codec.FrameMessage) and first.sensor == "mono" and first.frame.stamp_ns == 5_000
    np.testing.assert_array_equal(first.frame.left, left)
    assert second == codec.EndOfStream(1)


def test_for_run_joins_the_session_named_in_the_run_folder(hub, tmp_path):
    session, endpoint = hub
    write_session_file(tmp_path, SessionInfo(SESSION, (endpoint,)))
    with Client.for_run(tmp_path, name="tester") as client:
        assert client.session_name == SESSION
        client.announce()
        assert not bus.wait_for_alive(session, SESSION, ["tester"], timeout_s=30.0)
