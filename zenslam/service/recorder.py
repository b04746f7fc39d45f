"""The recorder process: every message under zenslam/<session>/ into run.mcap, plus what viewers draw.

Each bus message is written as it came, on the topic of its key without the session prefix
(``/sensor/frame``, ``/frontend/pose``, ...), with its protobuf schema embedded; sensor frames'
images are stored as lossless PNG (``recorder.frame_images``), which decode to the same pixels,
once: by default (``recorder.image_format`` frame) they are the ``/camera/left`` and
``/camera/right`` foxglove.CompressedImage messages that viewers draw, and the ``/sensor/frame``
message follows them without its images (``mcap_io.iter_messages`` puts them back). Alongside, for
Foxglove and rerun: ``/camera/*`` as separate PNG or JPEG copies when ``image_format`` says so,
``/tf`` (foxglove.FrameTransform world -> camera for every pose) and ``/map/points``
(foxglove.PointCloud of the map as rebuilt from keyframes and map updates, at most one per
``recorder.map_points_period_s`` of sensor time, and the final map; the final map does not depend
on the order the stages' messages arrive in, a cloud before it shows the map as it stood when it
was written, which may lack a keyframe whose message was still on its way). Log and publish
times are the messages' own ``stamp_ns`` (messages without one, such as statuses, take the
latest stamp of their stage's messages), so a lockstep run's timeline depends neither on the wall
clock nor on the order different stages' messages arrive in.

The subscription is lossless: its callback only enqueues into a bounded queue (blocking zenoh,
hence the publishers, when full) and one worker thread encodes and writes. The process ends on
SIGINT, when its parent is gone, or when every stage it follows has come and gone; it then drains
the queue and writes the MCAP summary and index.
"""

from __future__ import annotations

import argparse
import logging
import queue
import sys
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from zenslam.runtime import bus
from zenslam.runtime.stage import StageStart, StopFlag, log_cpu_times, run_stage, yield_cpu
from zenslam.schemas import codec, keys
from zenslam.schemas.map_update import MapUpdate
from zenslam.service import mcap_io
from zenslam.service.recorder_config import RECORDING_NAME, RecorderConfig

logger = logging.getLogger(__name__)

STAGE = "recorder"
CAMERA_TOPICS = mcap_io.CAMERA_TOPICS
TF_TOPIC = "/tf"
MAP_POINTS_TOPIC = "/map/points"
WORLD_FRAME = "world"
CAMERA_FRAME = "camera"
_NS_PER_S = 1_000_000_000


class MapAccumulator:
    """The map as the bus tells it: keyframe poses and point positions from keyframes, then map updates.

    Map updates replace what they list and delete what they remove (their replacement
    semantics), so the last state equals the backend's map as far as its updates said.

    Keyframes come from the frontend and updates from the backend, so an update about a keyframe
    or its points can arrive before the keyframe's own message. What an update says is always
    newer (the backend wrote it after it had the keyframe), so a keyframe's message adds only the
    poses and points no update has named yet, removed ones included: the map then does not depend
    on the order the two stages' messages arrive in.
    """

    def __init__(self) -> None:
        self.keyframe_stamps_ns: dict[int, int] = {}
        self.keyframe_poses: dict[int, np.ndarray] = {}  # id -> T_world_cam (4, 4)
        self.points: dict[int, np.ndarray] = {}  # id -> p_world (3,) metres
        self._removed_keyframes: set[int] = set()
        self._removed_points: set[int] = set()

    def add_keyframe(self, keyframe: codec.KeyframeMessage) -> None:
        """A new keyframe's pose and the map points it created, where no map update has named them."""
        self.keyframe_stamps_ns[keyframe.id] = keyframe.stamp_ns
        if keyframe.id not in self.keyframe_poses and keyframe.id not in self._removed_keyframes:
            self.keyframe_poses[keyframe.id] = np.array(keyframe.T_world_cam, dtype=float)
        for point_id, p_world in zip(keyframe.new_point_ids.tolist(), np.asarray(keyframe.new_points_world, dtype=float)):
            if point_id not in self.points and point_id not in self._removed_points:
                self.points[point_id] = p_world

    def apply(self, update: MapUpdate) -> None:
        """Replace the listed keyframe poses and points, delete the removed ones."""
        for correction in update.keyframes:
            self.keyframe_poses[correction.id] = np.array(correction.T_world_cam, dtype=float)
        for point_id, p_world in zip(update.point_ids.tolist(), np.asarray(update.p_world, dtype=float)):
            self.points[point_id] = p_world
        removed_points = update.removed_point_ids.tolist()
        for point_id in removed_points:
            self.points.pop(point_id, None)
        self._removed_points.update(removed_points)
        removed_keyframes = update.removed_keyframe_ids.tolist()
        for keyframe_id in removed_keyframes:
            self.keyframe_poses.pop(keyframe_id, None)
        self._removed_keyframes.update(removed_keyframes)

    def point_array(self) -> tuple[np.ndarray, np.ndarray]:
        """(ids (P,) int64, p_world (P, 3) metres), ordered by id."""
        ids = np.array(sorted(self.points), dtype=np.int64)
        p_world = np.array([self.points[i] for i in ids.tolist()], dtype=float).reshape(-1, 3)
        return ids, p_world

    def keyframe_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """(stamps_ns (K,) int64, T_world_cam (K, 4, 4)) of the keyframes still in the map, oldest first.
        A keyframe known only from map updates (its own message lost with a crashed recorder's open
        chunk) has no stamp and is left out."""
        unstamped = [i for i in self.keyframe_poses if i not in self.keyframe_stamps_ns]
        if unstamped:
            logger.warning("%d keyframe(s) without their keyframe message (e.g. %d) are left out of the keyframe trajectory", len(unstamped), unstamped[0])
        ids = sorted((self.keyframe_stamps_ns[i], i) for i in self.keyframe_poses if i in self.keyframe_stamps_ns)
        stamps = np.array([stamp for stamp, _ in ids], dtype=np.int64)
        poses = np.array([self.keyframe_poses[i] for _, i in ids], dtype=float).reshape(-1, 4, 4)
        return stamps, poses


def _set_stamp(timestamp, stamp_ns: int) -> None:
    timestamp.seconds, timestamp.nanos = divmod(int(stamp_ns), _NS_PER_S)


def compressed_image(image: np.ndarray, stamp_ns: int, config: RecorderConfig, frame_id: str = CAMERA_FRAME) -> bytes:
    """A foxglove.CompressedImage of a uint8 grey image: JPEG when ``config.image_format`` says so, else PNG."""
    if config.image_format == "jpeg":
        ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, config.jpeg_quality])
        if not ok:
            raise mcap_io.RecordingError(f"OpenCV could not encode a {image.dtype} {image.shape} image as JPEG")
        return compressed_image_message(encoded.tobytes(), "jpeg", stamp_ns, frame_id)
    return compressed_image_message(codec.png_bytes(image, config.png_compression), "png", stamp_ns, frame_id)


def compressed_image_message(data: bytes, image_format: str, stamp_ns: int, frame_id: str = CAMERA_FRAME) -> bytes:
    """A foxglove.CompressedImage of already encoded image ``data`` ("png" or "jpeg")."""
    msg = CompressedImage(frame_id=frame_id, data=data, format=image_format)
    _set_stamp(msg.timestamp, stamp_ns)
    return msg.SerializeToString()


def frame_transform(pose: PoseInFrame) -> bytes:
    """The foxglove.FrameTransform parent ``pose.frame_id`` -> child ``camera`` of a PoseInFrame."""
    msg = FrameTransform(parent_frame_id=pose.frame_id or WORLD_FRAME, child_frame_id=CAMERA_FRAME)
    msg.timestamp.CopyFrom(pose.timestamp)
    msg.translation.x, msg.translation.y, msg.translation.z = pose.pose.position.x, pose.pose.position.y, pose.pose.position.z
    msg.rotation.CopyFrom(pose.pose.orientation)
    return msg.SerializeToString()


def point_cloud(p_world: np.ndarray, stamp_ns: int) -> bytes:
    """A foxglove.PointCloud of (P, 3) points in metres, world frame, as float32 x, y, z."""
    msg = PointCloud(frame_id=WORLD_FRAME, point_stride=12)
    _set_stamp(msg.timestamp, stamp_ns)
    msg.pose.orientation.w = 1.0
    for offset, name in enumerate("xyz"):
        msg.fields.add(name=name, offset=4 * offset, type=PackedElementField.FLOAT32)
    msg.data = np.ascontiguousarray(p_world, dtype="<f4").tobytes()
    return msg.SerializeToString()


def _stamp_of(decoded: object) -> int | None:
    """A decoded message's stamp (0 is one: a clip may start at 0), None for a message without one."""
    if isinstance(decoded, codec.FrameMessage):
        return int(decoded.frame.stamp_ns)
    stamp_ns = getattr(decoded, "stamp_ns", None)
    return None if stamp_ns is None else int(stamp_ns)


# A topic's first segment names the stage that publishes it, but for the source's sensor data.
_STAGE_OF_TOPIC_ROOT = {"sensor": "source"}


def _stage_of(topic: str) -> str:
    root = topic.split("/", 2)[1] if topic.startswith("/") else topic
    return _STAGE_OF_TOPIC_ROOT.get(root, root)


# Schemas whose messages carry what a recording derives (the map, the ends of the stages' streams).
_CARRIED_STATE = {codec.KEYFRAME, codec.MAP_UPDATE, codec.SENSOR_FRAME, codec.TRACKING_STATE}


class Recorder:
    """Writes one bus message and what is derived from it; testable without the bus."""

    def __init__(self, writer: mcap_io.RecordingWriter, config: RecorderConfig, session: str):
        self.writer = writer
        self.config = config
        self.session = session
        self.map = MapAccumulator()
        # Per stage (a topic's first segment), its latest stamp: the log time of its messages without
        # one. A stage's messages arrive in the order it sent them, those of different stages in any.
        self.stage_stamps_ns: dict[str, int] = {}
        self.undecodable = 0  # messages recorded raw whose derived channels could not be made
        self._map_written_ns: int | None = None  # log time of the last /map/points cloud
        self._map_changed_ns: int | None = None  # log time of a map change no cloud shows yet
        self.ended_topics: set[str] = set()  # topics whose end-of-stream message has been recorded

    def record(self, key: str, encoding: str, data: bytes) -> None:
        """Record the message ``data`` that arrived on zenoh ``key`` with ``encoding`` (which names its schema)."""
        topic = mcap_io.topic_for_key(key, self.session)
        schema = mcap_io.schema_from_encoding(encoding)
        decoded = None
        try:
            decoded = mcap_io.DECODERS[schema](data) if schema in mcap_io.DECODERS else None
        except codec.MessageError as exc:
            self.undecodable += 1
            logger.warning("%s: %s; recorded as is, nothing derived from it", topic, exc)
        log_time = self._log_time(topic, _stamp_of(decoded))
        stored = data
        if isinstance(decoded, codec.FrameMessage) and self.config.image_format == "frame":
            # Each image once: the viewers' camera messages first, then the frame that refers to them.
            stored, pngs = codec.sensor_frame_images_apart(data, self.config.png_compression)
            for camera_topic, png in zip(CAMERA_TOPICS, pngs):
                self.writer.write(camera_topic, mcap_io.COMPRESSED_IMAGE, compressed_image_message(png, "png", log_time), log_time)
        elif isinstance(decoded, codec.FrameMessage) and self.config.frame_images == "png":
            stored = codec.sensor_frame_as_png(data, self.config.png_compression)
        self.writer.write(topic, schema, stored, log_time)
        if isinstance(decoded, codec.EndOfStream):
            self.ended_topics.add(topic)
        if decoded is not None:
            self._derive(decoded, data, log_time)

    def _derive(self, decoded: object, data: bytes, log_time: int) -> None:
        if isinstance(decoded, codec.FrameMessage):
            if self.config.image_format == "frame":
                return  # the camera messages are the frame's own images, written with it
            for topic, image in zip(CAMERA_TOPICS, (decoded.frame.left, decoded.frame.right)):
                if image is not None:
                    self.writer.write(topic, mcap_io.COMPRESSED_IMAGE, compressed_image(image, log_time, self.config), log_time)
        elif isinstance(decoded, codec.StampedPose):
            self.writer.write(TF_TOPIC, mcap_io.FRAME_TRANSFORM, frame_transform(PoseInFrame.FromString(data)), log_time)
        elif isinstance(decoded, codec.KeyframeMessage):
            self.map.add_keyframe(decoded)
            self._map_changed(log_time)
        elif isinstance(decoded, MapUpdate):
            self.map.apply(decoded)
            self._map_changed(log_time)

    def carry_over(self, crashed: Path) -> mcap_io.RecoveryReport:
        """Copy the messages of a crashed recorder's file into this recording, as they were stored
        (its open chunk is lost), and take from them what the recording derives later: the map of
        the final point cloud, the ended streams, the latest stamp."""
        report = mcap_io.RecoveryReport(messages={})
        end = mcap_io.StreamEnd()
        for schema, channel, message in mcap_io.stream_messages(crashed, end=end):
            schema_name = schema.name if schema is not None else None
            self.writer.write(channel.topic, schema_name, message.data, message.log_time, message.publish_time)
            report.messages[channel.topic] = report.messages.get(channel.topic, 0) + 1
            self._log_time(channel.topic, int(message.log_time))
            if schema_name not in _CARRIED_STATE:
                continue
            try:
                decoded = mcap_io.DECODERS[schema_name](message.data)
            except codec.MessageError:
                continue  # a sensor frame stored without its images: only its end of stream matters here
            if isinstance(decoded, codec.EndOfStream):
                self.ended_topics.add(channel.topic)
            elif isinstance(decoded, codec.KeyframeMessage):
                self.map.add_keyframe(decoded)
            elif isinstance(decoded, MapUpdate):
                self.map.apply(decoded)
        report.complete, report.stop_reason = end.complete, end.reason
        return report

    def _log_time(self, topic: str, stamp_ns: int | None) -> int:
        stage = _stage_of(topic)
        if stamp_ns is None:
            return self.stage_stamps_ns.get(stage, 0)
        self.stage_stamps_ns[stage] = max(self.stage_stamps_ns.get(stage, 0), stamp_ns)
        return stamp_ns

    def finish(self) -> None:
        """Write what is still due: the latest map, if its last change came too soon after the previous cloud."""
        if self._map_changed_ns is not None:
            self._write_map(self._map_changed_ns)

    def _map_changed(self, log_time: int) -> None:
        # Each cloud holds the whole map: one per change would grow the file with the square of the map.
        period_ns = round(self.config.map_points_period_s * _NS_PER_S)
        if self._map_written_ns is None or log_time - self._map_written_ns >= period_ns:
            self._write_map(log_time)
        else:
            self._map_changed_ns = log_time

    def _write_map(self, log_time: int) -> None:
        _, p_world = self.map.point_array()
        self.writer.write(MAP_POINTS_TOPIC, mcap_io.POINT_CLOUD, point_cloud(p_world, log_time), log_time)
        self._map_written_ns, self._map_changed_ns = log_time, None


# The stream each followed stage ends when its input is done: a stage gone without ending it crashed,
# and its supervisor may restart it.
_STREAM_OF = {"source": keys.sensor_frame, "frontend": keys.frontend_state, "backend": keys.backend_map_update}


class _Followed:
    """Liveliness of the stages the recorder follows: done once each has appeared and gone.

    A stage gone without ending its stream crashed; it counts as gone for good only after
    ``restart_grace_s`` seconds without coming back (a supervisor restarts a crashed backend, and the
    new one's messages belong in the recording too)."""

    def __init__(self, session: bus.Session, session_name: str, stages: Iterable[str], restart_grace_s: float = 60.0):
        self.stages = set(stages)
        self.seen: set[str] = set()
        self.gone: dict[str, float] = {}  # stage -> when its token vanished (monotonic seconds)
        self.restart_grace_s = restart_grace_s
        self._prefix = keys.alive(session_name, "x")[:-1]
        self._streams = {stage: mcap_io.topic_for_key(_STREAM_OF[stage](session_name), session_name) for stage in self.stages if stage in _STREAM_OF}
        self._subscriber = None
        if self.stages:
            self._subscriber = bus.watch_tokens(session, keys.all_alive(session_name), capacity=64)

    def _take(self) -> None:
        while self._subscriber is not None and (sample := self._subscriber.try_recv()) is not None:
            name = str(sample.key_expr).removeprefix(self._prefix)
            if bus.token_appeared(sample):
                self.seen.add(name)
                self.gone.pop(name, None)  # back: a restart
            elif name in self.seen:
                self.gone[name] = time.monotonic()

    def _gone_for_good(self, stage: str, ended_topics: set[str]) -> bool:
        ended = stage not in self._streams or self._streams[stage] in ended_topics
        if stage not in self.gone:
            # Never seen: done only if it ended its stream before this recorder came (a restarted recorder).
            return stage not in self.seen and stage in self._streams and ended
        return ended or time.monotonic() - self.gone[stage] >= self.restart_grace_s

    def done(self, ignored: frozenset[str] = frozenset(), ended_topics: set[str] | frozenset[str] = frozenset()) -> bool:
        """Every followed stage but the ``ignored`` has appeared and gone for good, having ended its
        stream (a topic in ``ended_topics``) or not come back within the grace (False when following none)."""
        self._take()
        ended = set(ended_topics)  # a copy: the writer thread adds to it
        return self._subscriber is not None and all(self._gone_for_good(stage, ended) for stage in self.stages - ignored)

    def none_running(self, ignored: frozenset[str] = frozenset()) -> bool:
        """No followed stage but the ``ignored`` is up now (those never seen are not waited for)."""
        self._take()
        return (self.stages & self.seen) - ignored <= set(self.gone)

    def close(self) -> None:
        if self._subscriber is not None:
            self._subscriber.undeclare()


class _BackendEnd:
    """Calls ``at_backend_end`` once the backend's map-update stream has been recorded to its end."""

    def __init__(self, recorder: Recorder, at_backend_end: Callable[[], None] | None):
        self._recorder = recorder
        self._at_backend_end = at_backend_end
        self._topic = mcap_io.topic_for_key(keys.backend_map_update(recorder.session), recorder.session)
        self.called = False

    def check(self) -> None:
        if self._at_backend_end is not None and not self.called and self._topic in self._recorder.ended_topics:
            self.called = True
            self._at_backend_end()

    def left_alone(self) -> frozenset[str]:
        """The stages not to wait for: the backend, once it has been asked what was wanted of it."""
        return frozenset({"backend"}) if self.called else frozenset()


class _Worker:
    """The writer thread: runs ``first`` (a crashed predecessor's messages carried over), then takes
    (key, encoding, bytes) from the queue and records them."""

    def __init__(self, recorder: Recorder, capacity: int, first: Callable[[], None] | None = None):
        self.queue: queue.Queue[tuple[str, str, bytes] | None] = queue.Queue(maxsize=capacity)
        self.recorder = recorder
        self.error: BaseException | None = None
        self.received = 0
        self.last_arrival = time.monotonic()
        self._first = first
        self.thread = threading.Thread(target=self._run, name="recorder-writer", daemon=True)
        self.thread.start()

    def on_sample(self, sample: bus.Sample) -> None:
        """zenoh's callback: enqueue only; blocks when the queue is full (back-pressure, nothing lost)."""
        self.queue.put((str(sample.key_expr), str(sample.encoding), sample.payload.to_bytes()))
        self.received += 1
        self.last_arrival = time.monotonic()

    def _run(self) -> None:
        if self._first is not None:
            try:
                self._first()
            except Exception as exc:
                logger.exception("carrying the crashed recording over failed")
                self.error = exc
        while (item := self.queue.get()) is not None:
            if self.error is not None:
                continue  # keep draining so publishers are not blocked by a failed writer
            try:
                self.recorder.record(*item)
            except Exception as exc:  # reported by record() once the thread is joined
                logger.exception("recording failed")
                self.error = exc

    def close(self) -> None:
        self.queue.put(None)
        self.thread.join()


def record(
    session: bus.Session,
    session_name: str,
    path: Path,
    config: RecorderConfig,
    should_stop: Callable[[], bool],
    follow: Iterable[str] = (),
    max_drain_s: float = 5.0,
    stop_grace_s: float = 5.0,
    at_backend_end: Callable[[], None] | None = None,
    restart_grace_s: float = 60.0,
    carry_over: Path | None = None,
) -> dict[str, int]:
    """Record the session's messages to the MCAP file ``path`` until every stage in ``follow`` has come
    and gone, or ``should_stop()``; returns the messages written per topic.

    ``at_backend_end`` is called once, on this thread, when the backend's map-update stream has
    ended (a backend then lingers, answering queries: the moment to ask it for its final map); the
    recording then ends without waiting for the backend to exit. A followed stage gone without
    ending its stream (a crash) is waited for ``restart_grace_s`` seconds: a supervisor may restart it.

    ``carry_over``: the file of a crashed recorder this one replaces; its messages (all but its open
    chunk) are written first, while the messages arriving meanwhile wait in the queue (a full queue
    holds the publishers back: nothing is lost), and the file is deleted once the recording is finished.

    Stopped, it still records for up to ``stop_grace_s`` seconds while a followed stage is up: a
    stop reaches the stages too, and what they send as they stop (their last results, their ends
    of stream) belongs in the recording. At the end it keeps taking messages until none has
    arrived for ``config.quiet_s`` seconds, or for at most ``max_drain_s`` seconds while
    publishers are still sending.
    """
    writer = mcap_io.RecordingWriter(path, chunk_size=config.chunk_size, compression=config.chunk_compression)
    recorder = Recorder(writer, config, session_name)
    worker = _Worker(recorder, config.queue, None if carry_over is None else lambda: _carry_over(recorder, carry_over))
    followed = _Followed(session, session_name, follow, restart_grace_s)
    try:
        # Declared before the liveliness token: whoever waits for the recorder to be alive knows it listens.
        subscriber = bus.declare_callback_subscriber(session, keys.everything(session_name), worker.on_sample)
        try:
            with bus.declare_alive(session, session_name, STAGE):
                logger.info("recording %s to %s", keys.everything(session_name), path)
                log_cpu_times("at stream start")
                ended = _BackendEnd(recorder, at_backend_end)
                while not should_stop() and not followed.done(ended.left_alone(), recorder.ended_topics) and worker.error is None:
                    ended.check()
                    time.sleep(0.02)
                ended.check()
                stop_until = time.monotonic() + stop_grace_s
                while not followed.none_running(ended.left_alone()) and time.monotonic() < stop_until and worker.error is None:
                    time.sleep(0.02)
                drain_until = time.monotonic() + max_drain_s
                while time.monotonic() - worker.last_arrival < config.quiet_s and time.monotonic() < drain_until:
                    time.sleep(0.02)  # take what is still arriving; the queue itself is emptied by the worker
        finally:
            subscriber.undeclare()
            followed.close()
    finally:
        worker.close()
        try:
            if worker.error is None:
                recorder.finish()
        finally:
            writer.finish()
    if worker.error is not None:
        raise mcap_io.RecordingError(f"recording to {path} failed: {worker.error}") from worker.error
    logger.info("wrote %d messages on %d topics to %s", sum(writer.counts.values()), len(writer.counts), path)
    if carry_over is not None:
        carry_over.unlink()  # its messages are in the finished recording
    return dict(writer.counts)


def _carry_over(recorder: Recorder, crashed: Path) -> None:
    started = time.perf_counter()
    report = recorder.carry_over(crashed)
    logger.info(
        "carried %d messages over from the crashed recording %s in %.1f s (%s)", report.total, crashed,
        time.perf_counter() - started, "complete" if report.complete else f"its open chunk lost: {report.stop_reason}",
    )  # fmt: skip


def set_aside(path: Path, restart: int) -> Path | None:
    """A restarted recorder's predecessor's file, moved to ``<stem>.crashed<N>.mcap`` beside it so that
    the recording can be written at ``path`` again; None when there is none."""
    if not path.exists():
        return None
    aside = path.with_name(f"{path.stem}.crashed{restart}{path.suffix}")
    path.replace(aside)
    logger.warning("restart %d: %s was left unfinished by the recorder before; carrying it over from %s", restart, path, aside)
    return aside


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``python -m zenslam.service.recorder --session S --output run.mcap [--follow STAGE] ...``
    (``--run-dir DIR`` instead of ``--output``: the run folder's outputs too, see ``recorded_run``)."""
    return run_stage(STAGE, __doc__, _run, argv, _add_arguments)


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--output", type=Path, help="the MCAP file to write (e.g. recordings/<run-id>/run.mcap)")
    target.add_argument(
        "--run-dir", type=Path,
        help="the run folder: write run.mcap there and, once the stages are done, the run's outputs (trajectory.tum, "
        "keyframes.tum, metrics.json, ...) as `zenslam run` does; for stages started with `zenslam stage`",
    )
    parser.add_argument(
        "--follow", action="append", default=[], metavar="STAGE",
        help="stage to follow: once every followed stage has appeared and exited, finish (repeatable)",
    )


def _run(stage: StageStart) -> None:
    """The recorder process: record the run's session to ``--output``, or to ``--run-dir`` with its outputs."""
    args = stage.args
    config = stage.section(STAGE, RecorderConfig)
    # Lockstep tracking waits for the recording too (its messages are lossless): keep pace there,
    # so that a crash loses no more than the open chunk.
    yield_cpu(0 if stage.mode() == "lockstep" else config.nice)
    restart_grace_s = stage.bus_config.start_timeout_s
    with stage.open_session() as session:
        if args.run_dir is None:
            crashed = set_aside(args.output, args.restart) if args.restart else None
            record(
                session, args.session, args.output, config, stage.stop, args.follow,
                restart_grace_s=restart_grace_s, carry_over=crashed,
            )  # fmt: skip
        else:
            _record_run(session, args, config, stage.stop, restart_grace_s)


_QUERY_TIMEOUT_S = 10.0  # seconds to wait for the backend's answer to the final trajectory query


def _record_run(
    session: bus.Session, args: argparse.Namespace, config: RecorderConfig, stop: StopFlag, restart_grace_s: float
) -> None:
    """Record to ``args.run_dir``/run.mcap, ask the backend for its final keyframe poses when its stream
    ends, then write the run's outputs from the recording."""
    from zenslam.runtime.backend_queries import query_trajectory
    from zenslam.service.recorded_run import write_recorded_outputs
    from zenslam.service.run_config import load_run_config
    from zenslam.service.run_output import write_config

    run_config = load_run_config(args.config)
    path = Path(args.run_dir) / RECORDING_NAME
    crashed = set_aside(path, args.restart) if args.restart else None
    if path.exists():
        raise mcap_io.RecordingError(f"{path} exists already; runs never overwrite: give another --run-dir")
    path.parent.mkdir(parents=True, exist_ok=True)
    if args.config is None or Path(args.config).resolve() != (path.parent / "config.yaml").resolve():
        write_config(path.parent, run_config)
    answers: list[codec.KeyframeTrajectoryMessage | None] = []

    def ask_backend() -> None:
        answers.append(query_trajectory(session, args.session, _QUERY_TIMEOUT_S))
        if answers[-1] is None:
            logger.warning("the backend did not answer the trajectory query; keyframes.tum has the frontend's keyframes")

    record(
        session, args.session, path, config, stop, args.follow, at_backend_end=ask_backend,
        restart_grace_s=restart_grace_s, carry_over=crashed,
    )  # fmt: skip
    result = write_recorded_outputs(path.parent, path, run_config, args.session, answers[0] if answers else None, stop())
    logger.info("wrote %s", ", ".join(p.name for p in result.files))


if __name__ == "__main__":
    sys.exit(main())
