"""The recorder: raw bus messages plus Foxglove images, transforms and point clouds; the map rebuilt from
keyframes and updates; recording a live session to MCAP."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap.reader import make_reader

from zenslam.camera import PinholeCalibration
from zenslam.errors import ConfigError
from zenslam.schemas import codec, keys
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.runtime import bus
from zenslam.service import mcap_io
from zenslam.service.recorder import MapAccumulator, Recorder, record
from zenslam.service.run_config import RecorderConfig
from zenslam.service.sources import SensorFrame

SESSION = "rec-test"
ENCODING = "application/protobuf;{}"
CAL = PinholeCalibration(50.0, 50.0, 32.0, 24.0, 64, 48, 0.1)


def _frame(i: int, seed: int = 0) -> bytes:
    rng = np.random.default_rng(seed + i)
    left = rng.integers(0, 256, (48, 64), dtype=np.uint8)
    right = np.roll(left, 3, axis=1)
    return codec.encode_sensor_frame(SensorFrame(i, 1_000_000 * (i + 1), left, right), CAL, "stereo")


def _keyframe(kf_id: int, stamp_ns: int, point_ids: list[int], points: np.ndarray) -> codec.KeyframeMessage:
    T = np.eye(4)
    T[0, 3] = kf_id
    n = 2
    return codec.KeyframeMessage(
        id=kf_id, stamp_ns=stamp_ns, frame_index=kf_id, T_world_cam=T, calibration=CAL, sensor="stereo",
        keypoints_px=np.zeros((n, 2), np.float32), levels=np.zeros(n, np.int16), angles_deg=np.zeros(n, np.float32),
        right_u=np.zeros(n, np.float32), depth_m=np.ones(n, np.float32), descriptors=np.zeros((n, 32), np.uint8),
        map_point_ids=np.full(n, -1, np.int64), scale_factors=np.ones(1), new_point_ids=np.array(point_ids, np.int64),
        new_points_world=np.asarray(points, float).reshape(-1, 3),
    )


def _update(
    kf_id: int, point_ids: list[int], points: np.ndarray, removed: list[int], stamp_ns: int = 0, removed_keyframes: tuple[int, ...] = ()
) -> MapUpdate:
    p = len(point_ids)
    T = np.eye(4)
    T[1, 3] = 5.0
    return MapUpdate(
        keyframe_id=kf_id, stamp_ns=stamp_ns, keyframes=(KeyframeCorrection(kf_id, T, np.full(2, -1, np.int64)),),
        point_ids=np.array(point_ids, np.int64), p_world=np.asarray(points, float).reshape(-1, 3),
        descriptors=np.zeros((p, 32), np.uint8), normals=np.zeros((p, 3)), min_distance_m=np.zeros(p), max_distance_m=np.zeros(p),
        removed_point_ids=np.array(removed, np.int64), removed_keyframe_ids=np.array(removed_keyframes, np.int64),
    )


def _record_all(tmp_path, messages, config=RecorderConfig()):
    path = tmp_path / "run.mcap"
    with mcap_io.RecordingWriter(path) as writer:
        recorder = Recorder(writer, config, SESSION)
        for key, schema, data in messages:
            recorder.record(key, ENCODING.format(schema), data)
        recorder.finish()
    return path, recorder


def _by_topic(path) -> dict[str, list[mcap_io.RecordedMessage]]:
    out: dict[str, list[mcap_io.RecordedMessage]] = {}
    for m in mcap_io.iter_messages(path):
        out.setdefault(m.topic, []).append(m)
    return out


@pytest.mark.parametrize(("frame_images", "image_format"), [("png", "frame"), ("png", "jpeg"), ("raw", "jpeg")])
def test_frames_are_recorded_losslessly_in_png_or_raw(tmp_path, frame_images, image_format):
    sent = [_frame(i) for i in range(3)] + [codec.encode_end_of_stream(codec.SENSOR_FRAME, 3)]
    messages = [(keys.sensor_frame(SESSION), codec.SENSOR_FRAME, f) for f in sent]
    path, _ = _record_all(tmp_path, messages, RecorderConfig(frame_images=frame_images, image_format=image_format))
    recorded = _by_topic(path)["/sensor/frame"]
    encoding = {"png": pb.IMAGE_ENCODING_PNG, "raw": pb.IMAGE_ENCODING_RAW}[frame_images]
    assert [pb.SensorFrame.FromString(m.data).image_encoding for m in recorded[:3]] == [encoding] * 3
    if frame_images == "raw":
        assert [m.data for m in recorded] == sent  # as it came
    for message, data in zip(recorded, sent):
        got, expected = mcap_io.decode(message), codec.decode_sensor_frame(data)
        if isinstance(expected, codec.EndOfStream):
            assert got == expected
            continue
        np.testing.assert_array_equal(got.frame.left, expected.frame.left)  # bit-exact
        np.testing.assert_array_equal(got.frame.right, expected.frame.right)
        assert (got.frame.index, got.frame.stamp_ns, got.calibration, got.sensor) == (
            expected.frame.index, expected.frame.stamp_ns, expected.calibration, expected.sensor
        )


def _stored(path) -> list[tuple[str, bytes]]:
    """(topic, bytes) of every message as stored, in file order (no images put back)."""
    with open(path, "rb") as f:
        return [(channel.topic, message.data) for _, channel, message in make_reader(f).iter_messages(log_time_order=False)]


def test_by_default_each_image_is_stored_once_as_the_viewers_camera_image(tmp_path):
    assert RecorderConfig().image_format == "frame"
    sent = [_frame(i) for i in range(3)]
    path, _ = _record_all(tmp_path, [(keys.sensor_frame(SESSION), codec.SENSOR_FRAME, f) for f in sent])
    stored = _stored(path)
    # Per frame: its left and right images for viewers, then the frame without them.
    assert [topic for topic, _ in stored] == ["/camera/left", "/camera/right", "/sensor/frame"] * 3
    for i, data in enumerate(sent):
        left, right, frame = (data for _, data in stored[3 * i : 3 * i + 3])
        stored_frame = pb.SensorFrame.FromString(frame)
        assert stored_frame.image_encoding == pb.IMAGE_ENCODING_PNG_APART and not stored_frame.left and not stored_frame.right
        expected = codec.decode_sensor_frame(data).frame
        for image_data, pixels in ((left, expected.left), (right, expected.right)):
            image = CompressedImage.FromString(image_data)
            assert image.format == "png" and image.timestamp.nanos == 1_000_000 * (i + 1)
            np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_UNCHANGED), pixels)
    # Read back through mcap_io, the frames are whole again: the images put back as PNG.
    recorded = _by_topic(path)
    assert len(recorded["/camera/left"]) == len(recorded["/camera/right"]) == 3
    for message, data in zip(recorded["/sensor/frame"], sent):
        assert pb.SensorFrame.FromString(message.data).image_encoding == pb.IMAGE_ENCODING_PNG
        got, expected = mcap_io.decode(message).frame, codec.decode_sensor_frame(data).frame
        np.testing.assert_array_equal(got.left, expected.left)
        np.testing.assert_array_equal(got.right, expected.right)
    only_frames = list(mcap_io.iter_messages(path, ["/sensor/frame"]))  # camera channels read, not returned
    assert [m.data for m in only_frames] == [m.data for m in recorded["/sensor/frame"]]


def test_a_stored_apart_frame_without_its_images_is_an_error_naming_it(tmp_path):
    path = tmp_path / "cut.mcap"
    stored, _ = codec.sensor_frame_images_apart(_frame(0))
    with mcap_io.RecordingWriter(path) as writer:
        writer.write("/sensor/frame", codec.SENSOR_FRAME, stored, 1_000_000)
    with pytest.raises(mcap_io.RecordingError, match=r"/sensor/frame message at 1000000 ns .* no /camera/left"):
        list(mcap_io.iter_messages(path, ["/sensor/frame"]))


def test_frame_images_for_viewers_need_png_frames():
    with pytest.raises(ConfigError, match="image_format=frame .*frame_images=raw"):
        RecorderConfig(frame_images="raw")


def test_viewer_images_are_lossless_png_on_request(tmp_path):
    config = RecorderConfig(image_format="png")
    path, _ = _record_all(tmp_path, [(keys.sensor_frame(SESSION), codec.SENSOR_FRAME, _frame(i)) for i in range(3)], config)
    topics = _by_topic(path)
    assert [m.schema for m in topics["/camera/left"]] == ["foxglove.CompressedImage"] * 3
    assert [m.log_time_ns for m in topics["/sensor/frame"]] == [1_000_000, 2_000_000, 3_000_000]
    raw = mcap_io.decode(topics["/sensor/frame"][1])
    for topic, expected in (("/camera/left", raw.frame.left), ("/camera/right", raw.frame.right)):
        image = CompressedImage.FromString(topics[topic][1].data)
        assert image.format == "png" and image.timestamp.nanos == 2_000_000
        decoded = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(decoded, expected)


def test_viewer_images_are_jpeg_copies_on_request(tmp_path):
    smooth = np.add.outer(np.arange(48), 2 * np.arange(64)).astype(np.uint8)  # a ramp, like natural images' large areas
    frame = codec.encode_sensor_frame(SensorFrame(0, 1_000_000, smooth, smooth), CAL, "stereo")
    path, _ = _record_all(tmp_path, [(keys.sensor_frame(SESSION), codec.SENSOR_FRAME, frame)], RecorderConfig(image_format="jpeg"))
    topics = _by_topic(path)
    image = CompressedImage.FromString(topics["/camera/left"][0].data)
    assert image.format == "jpeg" and image.data[:2] == b"\xff\xd8"
    decoded = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_UNCHANGED)
    raw = mcap_io.decode(topics["/sensor/frame"][0]).frame.left
    # Lossy, but close: quality 90 on the test's smooth image stays within a few grey levels.
    assert decoded.shape == raw.shape and np.abs(decoded.astype(int) - raw.astype(int)).mean() < 3.0


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_every_chunk_compression_reads_back(tmp_path, compression):
    config = RecorderConfig(chunk_compression=compression)
    path, _ = _record_all(tmp_path, [(keys.sensor_frame(SESSION), codec.SENSOR_FRAME, _frame(i)) for i in range(3)], config)
    recorded = [mcap_io.decode(m).frame for m in _by_topic(path)["/sensor/frame"]]
    assert len(recorded) == 3
    for i, frame in enumerate(recorded):
        sent = codec.decode_sensor_frame(_frame(i)).frame
        np.testing.assert_array_equal(frame.left, sent.left)
        np.testing.assert_array_equal(frame.right, sent.right)


def test_poses_get_a_frame_transform_and_unstamped_messages_the_last_stamp(tmp_path):
    T = np.eye(4)
    T[:3, 3] = (1.0, 2.0, 3.0)
    T[:3, :3] = cv2.Rodrigues(np.array([0.1, -0.2, 0.3]))[0]
    status = codec.encode_stage_status(codec.StageStatusMessage("frontend", "running", 1))
    path, _ = _record_all(tmp_path, [
        (keys.frontend_pose(SESSION), codec.POSE_IN_FRAME, codec.encode_pose_in_frame(codec.StampedPose(7_000, T))),
        (keys.status(SESSION, "frontend"), codec.STAGE_STATUS, status),
    ])
    topics = _by_topic(path)
    tf = FrameTransform.FromString(topics["/tf"][0].data)
    assert (tf.parent_frame_id, tf.child_frame_id) == ("world", "camera")
    assert (tf.translation.x, tf.translation.y, tf.translation.z) == (1.0, 2.0, 3.0)
    pose = mcap_io.decode(topics["/frontend/pose"][0]).T_world_cam
    q = np.array([tf.rotation.w, tf.rotation.x, tf.rotation.y, tf.rotation.z])
    from zenslam.geometry import quat_wxyz_to_R

    np.testing.assert_allclose(quat_wxyz_to_R(q), pose[:3, :3], atol=1e-12)
    assert topics["/frontend/status"][0].log_time_ns == 7_000


def test_unstamped_messages_take_their_own_stages_latest_stamp_and_a_zero_stamp_is_a_stamp(tmp_path):
    # Stages publish independently: the log time of a status must not depend on what another stage
    # sent just before it arrived. A clip may start at stamp 0 (KITTI does): its answer is logged at 0.
    path, _ = _record_all(tmp_path, [
        (keys.sensor_frame(SESSION), codec.SENSOR_FRAME, _frame(8)),  # stamp 9_000_000
        (keys.backend_map_update(SESSION), codec.MAP_UPDATE, codec.encode_map_update(_update(0, [], [], removed=[], stamp_ns=0))),
        (keys.frontend_pose(SESSION), codec.POSE_IN_FRAME, codec.encode_pose_in_frame(codec.StampedPose(7_000, np.eye(4)))),
        (keys.sensor_frame(SESSION), codec.SENSOR_FRAME, _frame(9)),  # stamp 10_000_000
        (keys.status(SESSION, "frontend"), codec.STAGE_STATUS, codec.encode_stage_status(codec.StageStatusMessage("frontend", "running", 1))),
        (keys.status(SESSION, "source"), codec.STAGE_STATUS, codec.encode_stage_status(codec.StageStatusMessage("source", "running", 2))),
        (keys.status(SESSION, "backend"), codec.STAGE_STATUS, codec.encode_stage_status(codec.StageStatusMessage("backend", "running", 1))),
    ])
    topics = _by_topic(path)
    assert [m.log_time_ns for m in topics["/backend/map_update"]] == [0]
    assert topics["/frontend/status"][0].log_time_ns == 7_000
    assert topics["/source/status"][0].log_time_ns == 10_000_000
    assert topics["/backend/status"][0].log_time_ns == 0


def test_map_accumulator_applies_replacements_and_removals():
    acc = MapAccumulator()
    acc.add_keyframe(_keyframe(0, 100, [1, 2, 3], np.arange(9.0)))
    acc.apply(_update(0, [2, 9], [[0, 0, 7.0], [1, 1, 1.0]], removed=[3]))
    ids, p_world = acc.point_array()
    assert ids.tolist() == [1, 2, 9]
    np.testing.assert_array_equal(p_world, [[0, 1, 2], [0, 0, 7], [1, 1, 1]])
    stamps, poses = acc.keyframe_trajectory()
    assert stamps.tolist() == [100] and poses[0, 1, 3] == 5.0


def test_the_map_does_not_depend_on_whether_an_update_arrives_before_its_keyframe():
    # The backend's updates about keyframe 1 (which moves point 5, removes point 6 and culls keyframe
    # 0) can reach a recorder before the frontend's message of keyframe 1 itself.
    keyframes = [_keyframe(0, 100, [1, 2], np.arange(6.0)), _keyframe(1, 200, [5, 6, 7], np.arange(9.0))]
    update = _update(1, [5], [[0, 0, 9.0]], removed=[6, 1], stamp_ns=200, removed_keyframes=(0,))
    in_order, update_first = MapAccumulator(), MapAccumulator()
    for acc, messages in ((in_order, [*keyframes, update]), (update_first, [keyframes[0], update, keyframes[1]])):
        for message in messages:
            acc.apply(message) if isinstance(message, MapUpdate) else acc.add_keyframe(message)
    for acc in (in_order, update_first):
        ids, p_world = acc.point_array()
        assert ids.tolist() == [2, 5, 7]
        np.testing.assert_array_equal(p_world, [[3, 4, 5], [0, 0, 9], [6, 7, 8]])
        stamps, poses = acc.keyframe_trajectory()
        assert stamps.tolist() == [200] and poses[0, 1, 3] == 5.0


def test_keyframes_and_map_updates_give_point_clouds(tmp_path):
    kf = codec.encode_keyframe(_keyframe(0, 500, [1, 2], [[0, 0, 1.0], [0, 0, 2.0]]))
    update = codec.encode_map_update(_update(0, [3], [[0, 0, 3.0]], removed=[1], stamp_ns=500))
    path, _ = _record_all(tmp_path, [
        (keys.frontend_keyframe(SESSION), codec.KEYFRAME, kf),
        (keys.backend_map_update(SESSION), codec.MAP_UPDATE, update),
    ])
    clouds = _by_topic(path)["/map/points"]
    assert [m.schema for m in clouds] == ["foxglove.PointCloud"] * 2
    last = PointCloud.FromString(clouds[-1].data)
    assert [f.name for f in last.fields] == ["x", "y", "z"] and last.point_stride == 12
    np.testing.assert_array_equal(np.frombuffer(last.data, "<f4").reshape(-1, 3), [[0, 0, 2], [0, 0, 3]])
    assert clouds[-1].log_time_ns == 500  # the update carries its keyframe's stamp


def test_point_clouds_come_at_most_once_per_period_and_the_final_map_last(tmp_path):
    keyframes = [
        (keys.frontend_keyframe(SESSION), codec.KEYFRAME, codec.encode_keyframe(_keyframe(i, stamp, [i], [[0, 0, float(i)]])))
        for i, stamp in enumerate((0, 400_000_000, 1_000_000_000, 1_300_000_000))
    ]
    path, _ = _record_all(tmp_path, keyframes, RecorderConfig(map_points_period_s=1.0))
    clouds = _by_topic(path)["/map/points"]
    # 0.4 s and 1.3 s came within a second of the previous cloud; 1.3 s is the last map: written at the end.
    assert [m.log_time_ns for m in clouds] == [0, 1_000_000_000, 1_300_000_000]
    assert [len(PointCloud.FromString(m.data).data) // 12 for m in clouds] == [1, 3, 4]
    path, _ = _record_all(tmp_path, keyframes, RecorderConfig(map_points_period_s=0.0))
    assert len(_by_topic(path)["/map/points"]) == 4


def test_an_undecodable_message_is_still_recorded(tmp_path):
    path, recorder = _record_all(tmp_path, [(keys.frontend_keyframe(SESSION), codec.KEYFRAME, b"\xff\xff\xff")])
    assert recorder.undecodable == 1
    assert [m.data for m in _by_topic(path)["/frontend/keyframe"]] == [b"\xff\xff\xff"]


class _LoopPolls:
    """A ``should_stop`` for ``record`` that never stops it, and counts its calls: the recording loop
    asks it before each look at its ending condition, so two calls after some moment mean a look
    taken after that moment found the recording not done."""

    def __init__(self) -> None:
        self._calls = 0
        self._changed = threading.Condition()

    def __call__(self) -> bool:
        with self._changed:
            self._calls += 1
            self._changed.notify_all()
        return False

    def wait_for_looks(self, n: int = 2, timeout_s: float = 20.0) -> bool:
        """True once ``n`` more calls have come from now (the recording still going); False after ``timeout_s``."""
        with self._changed:
            until = self._calls + n
            return self._changed.wait_for(lambda: self._calls >= until, timeout=timeout_s)


def _tell_when_recorded(monkeypatch, topic: str) -> threading.Event:
    """An event set once a Recorder has recorded (and taken what it derives from) a message on ``topic``."""
    recorded = threading.Event()
    original = Recorder.record

    def record_and_tell(self, key: str, encoding: str, data: bytes) -> None:
        original(self, key, encoding, data)
        if mcap_io.topic_for_key(key, self.session) == topic:
            recorded.set()

    monkeypatch.setattr(Recorder, "record", record_and_tell)
    return recorded


def test_record_a_session_until_stopped(tmp_path):
    hub_endpoint = bus.free_tcp_endpoint()
    path = tmp_path / "live.mcap"
    stop = threading.Event()
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub, bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
        result: dict = {}
        thread = threading.Thread(target=lambda: result.update(record(hub, SESSION, path, RecorderConfig(queue=2, quiet_s=0.2), stop.is_set)))
        thread.start()
        assert not bus.wait_for_alive(peer, SESSION, ["recorder"], timeout_s=10.0)
        publisher = bus.declare_publisher(peer, keys.frontend_state(SESSION), codec.TRACKING_STATE, "lossless")
        assert bus.wait_for_subscribers(publisher, timeout_s=5.0)
        # A second subscriber in the recorder's session: once it has the end of stream, so has the recorder.
        arrived = threading.Event()
        watcher = hub.declare_subscriber(
            keys.frontend_state(SESSION),
            lambda sample: isinstance(codec.decode_tracking_state(sample.payload.to_bytes()), codec.EndOfStream) and arrived.set(),
        )
        for i in range(50):
            publisher.put(codec.encode_tracking_state(codec.TrackingStateMessage(i, 10 * (i + 1), "ok")))
        publisher.put(codec.encode_end_of_stream(codec.TRACKING_STATE, 50))
        assert arrived.wait(timeout=20.0), "the end of stream did not arrive"
        watcher.undeclare()
        stop.set()
        thread.join(timeout=20)
        assert not thread.is_alive()
    assert result == {"/frontend/state": 51}
    states = [m for m in mcap_io.iter_messages(path)]
    assert [m.log_time_ns for m in states] == [10 * (i + 1) for i in range(50)] + [500]


def test_recording_ends_by_itself_once_the_followed_stages_have_come_and_gone(tmp_path, monkeypatch):
    hub_endpoint = bus.free_tcp_endpoint()
    path = tmp_path / "follow.mcap"
    frames_ended = _tell_when_recorded(monkeypatch, "/sensor/frame")
    polls = _LoopPolls()
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub, bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
        result: dict = {}
        config = RecorderConfig(quiet_s=0.1)
        thread = threading.Thread(target=lambda: result.update(record(hub, SESSION, path, config, polls, ["source"])))
        thread.start()
        assert not bus.wait_for_alive(peer, SESSION, ["recorder"], timeout_s=10.0)
        token = bus.declare_alive(peer, SESSION, "source")
        publisher = bus.declare_publisher(peer, keys.status(SESSION, "source"), codec.STAGE_STATUS, "lossless")
        assert bus.wait_for_subscribers(publisher, timeout_s=5.0)
        frames = bus.declare_publisher(peer, keys.sensor_frame(SESSION), codec.SENSOR_FRAME, "lossless")
        publisher.put(codec.encode_stage_status(codec.StageStatusMessage("source", "finished", 3)))
        frames.put(codec.encode_end_of_stream(codec.SENSOR_FRAME, 3))
        # The end of stream recorded, the recorder must not end while the source is still there: it
        # looks at its ending condition again (twice) and goes on.
        assert frames_ended.wait(timeout=20.0), "the end of stream was not recorded"
        assert polls.wait_for_looks(), "the recording ended with the source still there"
        assert thread.is_alive()
        token.undeclare()
        thread.join(timeout=10)
        assert not thread.is_alive()
    assert result == {"/source/status": 1, "/sensor/frame": 1}
    assert mcap_io.has_summary(path)


def test_a_followed_stage_gone_without_ending_its_stream_is_waited_for_while_it_may_be_restarted(tmp_path):
    """A crashed backend (its token gone, its map-update stream not ended) is not the end of the
    recording: its restarted successor's messages are recorded too; gone for good once it ended its
    stream. One that never comes back is given up after the restart grace."""
    hub_endpoint = bus.free_tcp_endpoint()
    path = tmp_path / "restart.mcap"
    polls = _LoopPolls()
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub, bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
        result: dict = {}
        config = RecorderConfig(quiet_s=0.1)
        thread = threading.Thread(
            target=lambda: result.update(record(hub, SESSION, path, config, polls, ["backend"], restart_grace_s=60.0))
        )
        thread.start()
        assert not bus.wait_for_alive(peer, SESSION, ["recorder"], timeout_s=10.0)
        status = bus.declare_publisher(peer, keys.status(SESSION, "backend"), codec.STAGE_STATUS, "lossless")
        # A watcher in the recorder's session: the backend's token gone for it is gone for the recorder's too.
        died = threading.Event()
        watcher = bus.watch_tokens(
            hub, keys.alive(SESSION, "backend"), lambda sample: not bus.token_appeared(sample) and died.set()
        )
        bus.declare_alive(peer, SESSION, "backend").undeclare()  # the first backend dies
        assert died.wait(timeout=20.0), "the backend's token did not vanish"
        watcher.undeclare()
        assert polls.wait_for_looks(), "the recording ended while the backend may come back"
        assert thread.is_alive()  # it may come back
        token = bus.declare_alive(peer, SESSION, "backend")  # restarted
        assert bus.wait_for_subscribers(status, timeout_s=5.0)
        status.put(codec.encode_stage_status(codec.StageStatusMessage("backend", "finished", 3)))
        updates = bus.declare_publisher(peer, keys.backend_map_update(SESSION), codec.MAP_UPDATE, "lossless")
        updates.put(codec.encode_end_of_stream(codec.MAP_UPDATE, 3))
        token.undeclare()
        thread.join(timeout=10)
        assert not thread.is_alive()
    assert result == {"/backend/status": 1, "/backend/map_update": 1}

    path = tmp_path / "gone.mcap"
    with bus.open_session(bus.BusConfig(listen=(hub_endpoint,))) as hub, bus.open_session(bus.BusConfig(connect=(hub_endpoint,))) as peer:
        started = time.monotonic()
        thread = threading.Thread(target=lambda: record(hub, SESSION, path, config, lambda: False, ["backend"], restart_grace_s=1.0))
        thread.start()
        assert not bus.wait_for_alive(peer, SESSION, ["recorder"], timeout_s=10.0)
        bus.declare_alive(peer, SESSION, "backend").undeclare()
        thread.join(timeout=10)
        assert not thread.is_alive() and time.monotonic() - started >= 1.0
    assert mcap_io.has_summary(path)


def test_a_restarted_recorder_carries_its_crashed_predecessors_messages_over(tmp_path):
    """A recorder killed mid-run leaves its finished chunks on disk: the one restarted in its place
    writes them first, as stored (frames without a second copy of their images), knows which streams
    had ended and which keyframes and points the map held, and goes on recording."""
    point = np.array([[1.0, 2.0, 3.0]])
    messages = [
        (keys.sensor_frame(SESSION), codec.SENSOR_FRAME, _frame(0)),
        (keys.frontend_keyframe(SESSION), codec.KEYFRAME, codec.encode_keyframe(_keyframe(0, 1_000_000, [7], point))),
        (keys.sensor_frame(SESSION), codec.SENSOR_FRAME, codec.encode_end_of_stream(codec.SENSOR_FRAME, 1)),
    ]
    crashed = tmp_path / "run.crashed1.mcap"
    writer = mcap_io.RecordingWriter(crashed, chunk_size=1)  # every message closes its chunk: all reach the file
    recorder = Recorder(writer, RecorderConfig(), SESSION)
    for key, schema, data in messages:
        recorder.record(key, ENCODING.format(schema), data)
    size = crashed.stat().st_size
    recorder.record(keys.frontend_keyframe(SESSION), ENCODING.format(codec.KEYFRAME), codec.encode_keyframe(_keyframe(1, 2_000_000, [8], point)))
    writer._stream.close()  # killed: no summary, no footer; and its last chunk cut short
    crashed.write_bytes(crashed.read_bytes()[: size + 40])
    (tmp_path / "unharmed").mkdir()
    expected = _by_topic(_record_all(tmp_path / "unharmed", messages)[0])

    path = tmp_path / "run.mcap"
    with mcap_io.RecordingWriter(path) as new_writer:
        restarted = Recorder(new_writer, RecorderConfig(), SESSION)
        report = restarted.carry_over(crashed)
        restarted.record(keys.frontend_state(SESSION), ENCODING.format(codec.TRACKING_STATE), codec.encode_end_of_stream(codec.TRACKING_STATE, 1))
        restarted.finish()
    assert not report.complete and report.stop_reason
    got = _by_topic(path)
    for topic in ("/sensor/frame", "/camera/left", "/camera/right", "/frontend/keyframe"):
        assert [m.data for m in got[topic]] == [m.data for m in expected[topic]], topic
    assert restarted.ended_topics == {"/sensor/frame", "/frontend/state"}
    assert set(restarted.map.points) == {7} and set(restarted.map.keyframe_poses) == {0}
    assert got["/map/points"], "the final map cloud is written from the carried-over keyframe"
