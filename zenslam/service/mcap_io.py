"""MCAP reading and writing for zenslam recordings: the one place where MCAP details live.

A recording holds every bus message on a channel named after its zenoh key without the session
prefix (``zenslam/<session>/frontend/pose`` -> ``/frontend/pose``), protobuf-encoded, with its
schema embedded as a FileDescriptorSet so any MCAP reader (Foxglove, rerun, mcap-protobuf-support)
can decode it. ``RecordingWriter`` registers schemas and channels lazily and numbers each
channel's messages; ``iter_messages`` reads a recording back, falling back to a streaming pass
over a file whose summary is missing (a killed writer), and ``decode`` turns a message into
zenslam's own types with ``zenslam.schemas.codec``.

Camera images are stored once: the recorder writes each frame's lossless PNG images as the
foxglove.CompressedImage messages of ``/camera/left`` and ``/camera/right`` (which viewers draw),
then the ``/sensor/frame`` message without them (IMAGE_ENCODING_PNG_APART), all with the frame's
stamp as log time. ``iter_messages`` gives ``/sensor/frame`` messages back whole (their images
put back, IMAGE_ENCODING_PNG); recordings whose frames hold their own images read as they are.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from google.protobuf.message import Message
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Header, Metadata, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from zenslam.errors import RecordingError, ZenslamError
from zenslam.schemas import codec, keys

logger = logging.getLogger(__name__)

MAGIC = b"\x89MCAP0\r\n"
ChunkCompression = Literal["zstd", "lz4", "none"]
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
COMPRESSED_IMAGE = "foxglove.CompressedImage"
SENSOR_FRAME_TOPIC = "/sensor/frame"
CAMERA_TOPICS = ("/camera/left", "/camera/right")  # foxglove.CompressedImage: a frame's left and right image
FRAME_TRANSFORM = "foxglove.FrameTransform"
POINT_CLOUD = "foxglove.PointCloud"

# Every schema a recording may hold: zenslam's bus messages and the Foxglove types added for viewers.
SCHEMA_CLASSES: dict[str, type[Message]] = {
    **codec.MESSAGE_CLASSES,
    COMPRESSED_IMAGE: CompressedImage,
    FRAME_TRANSFORM: FrameTransform,
    POINT_CLOUD: PointCloud,
}

# Schema name -> codec decoder giving zenslam's own types.
DECODERS: dict[str, Callable[[bytes], Any]] = {
    codec.SENSOR_FRAME: codec.decode_sensor_frame,
    codec.TRACKING_STATE: codec.decode_tracking_state,
    codec.KEYFRAME: codec.decode_keyframe,
    codec.MAP_UPDATE: codec.decode_map_update,
    codec.STAGE_STATUS: codec.decode_stage_status,
    codec.KEYFRAME_TRAJECTORY: codec.decode_keyframe_trajectory,
    codec.MAP_SNAPSHOT: codec.decode_map_snapshot,
    codec.LOOP: codec.decode_loop,
    codec.POSE_IN_FRAME: codec.decode_pose_in_frame,
}


def topic_for_key(key: str, session: str) -> str:
    """The MCAP topic of a zenoh key of ``session``: the key without ``zenslam/<session>``, with a leading '/'."""
    prefix = keys.session_prefix(session)
    if key.startswith(prefix + "/"):
        return key[len(prefix):]
    return "/" + key.lstrip("/")


def schema_from_encoding(encoding: str) -> str | None:
    """The schema name a zenoh encoding string carries (``application/protobuf;zenslam.Keyframe``), or None."""
    _, sep, schema = encoding.partition(";")
    return schema or None if sep else None


def schema_data(name: str) -> bytes:
    """The serialized FileDescriptorSet of schema ``name`` (with its dependencies), as MCAP embeds it."""
    cls = SCHEMA_CLASSES.get(name)
    if cls is None:
        raise RecordingError(f"schema {name!r} is not one of zenslam's recorded schemas {sorted(SCHEMA_CLASSES)}")
    return build_file_descriptor_set(cls).SerializeToString()


@dataclass(frozen=True)
class RecordedMessage:
    """One message of a recording: its topic, schema name, times (ns) and protobuf bytes."""

    topic: str
    schema: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes


class _UnbufferedFile:
    """A file whose every write goes straight to the OS (mcap's Writer would buffer a raw FileIO itself)."""

    def __init__(self, path: Path):
        self._raw = open(path, "wb", buffering=0)  # noqa: SIM115 - closed by close()

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            view = view[self._raw.write(view):]
        return len(data)

    def tell(self) -> int:
        return self._raw.tell()

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self._raw.close()


class RecordingWriter:
    """Writes protobuf messages to an MCAP file with compressed chunks, registering schemas and channels on first use.

    The file is opened unbuffered so every finished chunk reaches the OS at once: a killed writer
    then loses only its open chunk (``zenslam recover`` restores the rest).
    """

    def __init__(
        self, path: str | Path, chunk_size: int = 4 * 1024 * 1024, profile: str = "zenslam", compression: ChunkCompression = "zstd",
    ):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stream = _UnbufferedFile(self.path)
        self._writer = Writer(self._stream, chunk_size=chunk_size, compression=_COMPRESSION[compression])
        self._writer.start(profile=profile, library="zenslam")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}  # topic -> (channel id, schema name)
        self._sequence: dict[int, int] = {}
        self.counts: dict[str, int] = {}  # messages written per topic
        self._finished = False

    def _schema_id(self, schema: str | None) -> int:
        if schema is None or schema not in SCHEMA_CLASSES:
            return 0  # MCAP's "no schema": the bytes are kept, undecodable by name
        if schema not in self._schemas:
            self._schemas[schema] = self._writer.register_schema(schema, "protobuf", schema_data(schema))
        return self._schemas[schema]

    def channel(self, topic: str, schema: str | None) -> int:
        """The id of ``topic``'s channel, registering it (and its schema) the first time."""
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != schema:
                raise RecordingError(f"topic {topic} carries {known[1]} and now {schema}; one topic, one schema")
            return known[0]
        channel_id = self._writer.register_channel(topic, "protobuf", self._schema_id(schema))
        self._channels[topic] = (channel_id, schema or "")
        self._sequence[channel_id] = 0
        return channel_id

    def write(self, topic: str, schema: str | None, data: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """Add one message; times in ns (publish time defaults to the log time)."""
        channel_id = self.channel(topic, schema)
        sequence = self._sequence[channel_id]
        self._sequence[channel_id] = sequence + 1
        publish = log_time_ns if publish_time_ns is None else publish_time_ns
        self._writer.add_message(channel_id, log_time=int(log_time_ns), data=data, publish_time=int(publish), sequence=sequence)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def finish(self) -> None:
        """Write the last chunk, the summary and the index, and close the file (idempotent)."""
        if self._finished:
            return
        self._finished = True
        try:
            self._writer.finish()
        finally:
            self._stream.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()


def check_magic(path: Path) -> None:
    """Raise RecordingError unless ``path`` exists and starts with the MCAP magic."""
    if not path.is_file():
        raise RecordingError(f"recording {path} does not exist; give the path of a run.mcap")
    with open(path, "rb") as f:
        head = f.read(len(MAGIC))
    if head != MAGIC:
        raise RecordingError(f"{path} is not an MCAP file (it does not start with the MCAP magic bytes)")


def has_summary(path: str | Path) -> bool:
    """True when the file ends with a complete footer and summary (a finished writer)."""
    path = Path(path)
    check_magic(path)
    try:
        with open(path, "rb") as f:
            make_reader(f).get_summary()
        return True
    except (McapError, EOFError, ValueError):
        return False


def _to_recorded(schema: Schema | None, channel: Channel, message: McapMessage) -> RecordedMessage:
    return RecordedMessage(
        channel.topic, schema.name if schema is not None else "", message.log_time, message.publish_time, message.sequence, message.data
    )


def iter_messages(path: str | Path, topics: Iterable[str] | None = None, log_time_order: bool = True) -> Iterator[RecordedMessage]:
    """The messages of ``topics`` (all when None) in a recording, oldest log time first; ``/sensor/frame``
    messages whole, with the images the recording stores apart put back.

    A file without its summary (the writer was killed) is read by a streaming pass up to its
    last complete record, in file order, with a warning that ``zenslam recover`` would index it.
    """
    path = Path(path)
    wanted = None if topics is None else set(topics)
    read = wanted if wanted is None or SENSOR_FRAME_TOPIC not in wanted else wanted | set(CAMERA_TOPICS)
    yield from _with_frame_images(path, _iter_stored(path, read, log_time_order), wanted)


def _iter_stored(path: Path, topics: set[str] | None, log_time_order: bool) -> Iterator[RecordedMessage]:
    """The messages of ``topics`` (all when None) as stored."""
    if has_summary(path):
        with open(path, "rb") as f:
            reader = make_reader(f)
            for schema, channel, message in reader.iter_messages(topics=topics, log_time_order=log_time_order):
                yield _to_recorded(schema, channel, message)
        return
    logger.warning("%s has no summary (its writer was killed?): reading it sequentially; `zenslam recover` fixes it", path)
    for schema, channel, message in stream_messages(path, topics):
        yield _to_recorded(schema, channel, message)


def _with_frame_images(path: Path, messages: Iterable[RecordedMessage], wanted: set[str] | None) -> Iterator[RecordedMessage]:
    """``messages`` with each stored-apart sensor frame given back its images (the camera messages
    just before it with its log time); camera messages pass only when ``wanted`` (None: all)."""
    images: dict[str, RecordedMessage] = {}  # camera topic -> its latest message, all at one log time
    for message in messages:
        if message.topic in CAMERA_TOPICS:
            if images and next(iter(images.values())).log_time_ns != message.log_time_ns:
                images.clear()
            images[message.topic] = message
            if wanted is None or message.topic in wanted:
                yield message
        elif message.topic == SENSOR_FRAME_TOPIC and message.schema == codec.SENSOR_FRAME:
            at_frame = {t: m for t, m in images.items() if m.log_time_ns == message.log_time_ns}
            images.clear()
            if codec.sensor_frame_images_are_apart(message.data):
                message = _joined_frame(path, message, at_frame)
            yield message
        else:
            yield message


def _joined_frame(path: Path, message: RecordedMessage, images: dict[str, RecordedMessage]) -> RecordedMessage:
    """The stored-apart sensor frame ``message`` with the PNG images of ``images`` (camera topic -> message) put back."""
    left_topic, right_topic = CAMERA_TOPICS
    pngs: dict[str, bytes] = {}
    for topic, image in images.items():
        compressed = CompressedImage.FromString(image.data)
        if compressed.format != "png":
            raise RecordingError(
                f"{path}: the {message.topic} message at {message.log_time_ns} ns stores its images on the camera "
                f"channels, but {topic} holds {compressed.format!r}, not the frame's PNG; the recording is inconsistent"
            )
        pngs[topic] = compressed.data
    if left_topic not in pngs:
        raise RecordingError(
            f"{path}: the {message.topic} message at {message.log_time_ns} ns stores its images on {left_topic} and "
            f"{right_topic}, but no {left_topic} message with that log time precedes it; the recording lost it"
        )
    data = codec.sensor_frame_with_images(message.data, pngs[left_topic], pngs.get(right_topic))
    return RecordedMessage(message.topic, message.schema, message.log_time_ns, message.publish_time_ns, message.sequence, data)


def stream_messages(
    path: Path, topics: set[str] | None = None, end: StreamEnd | None = None
) -> Iterator[tuple[Schema | None, Channel, McapMessage]]:
    """Every complete message record of ``path`` in file order, stopping quietly at a truncated tail
    (``end``, if given, says how the pass ended)."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    for record in stream_records(path, end):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, McapMessage):
            channel = channels.get(record.channel_id)
            if channel is not None and (topics is None or channel.topic in topics):
                yield schemas.get(channel.schema_id), channel, record


@dataclass
class StreamEnd:
    """Where a streaming pass stopped: cleanly at the footer, or at a truncated/corrupt record."""

    complete: bool = False
    reason: str = ""


def stream_records(path: str | Path, end: StreamEnd | None = None) -> Iterator[Any]:
    """The records of ``path`` in file order (chunks decompressed); a truncated tail ends the pass.

    ``end`` (if given) is filled in with how the pass ended.
    """
    path = Path(path)
    check_magic(path)
    end = end if end is not None else StreamEnd()
    with open(path, "rb") as f:
        records = StreamReader(f, skip_magic=False).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                end.complete = True
                return
            except (McapError, EOFError, ValueError, struct.error) as exc:  # struct: a cut inside a length field
                # A killed writer leaves a half-written chunk: everything before it is intact.
                end.reason = f"{type(exc).__name__}: {exc}"
                return
            yield record


def decode(message: RecordedMessage) -> Any:
    """The zenslam form of a recorded message (codec's decoder for its schema)."""
    decoder = DECODERS.get(message.schema)
    if decoder is None:
        raise RecordingError(
            f"topic {message.topic}: schema {message.schema!r} has no zenslam decoder; use mcap-protobuf-support to read it"
        )
    return decoder(message.data)


def iter_decoded(path: str | Path, topics: Iterable[str]) -> Iterator[tuple[RecordedMessage, Any]]:
    """(message, decoded) for every message of ``topics`` in log-time order."""
    for message in iter_messages(path, topics):
        yield message, decode(message)


@dataclass
class RecoveryReport:
    """What a recovery pass kept: messages per topic, schemas, channels, and how the input ended."""

    messages: dict[str, int]
    schemas: int = 0
    channels: int = 0
    attachments: int = 0
    metadata: int = 0
    complete: bool = False  # the input ended with its footer: nothing was lost
    stop_reason: str = ""  # why the pass stopped early (a truncated or corrupt record)

    @property
    def total(self) -> int:
        return sum(self.messages.values())


def recover(broken: str | Path, fixed: str | Path, chunk_size: int = 4 * 1024 * 1024) -> RecoveryReport:
    """Copy every complete record of ``broken`` (e.g. a killed recorder's file) into an indexed MCAP ``fixed``.

    A streaming pass keeps every finished chunk and message up to the first truncated or corrupt
    record; the output gets a fresh summary and index so any seeking reader opens it.
    """
    broken, fixed = Path(broken), Path(fixed)
    if broken.resolve() == fixed.resolve():
        raise RecordingError(f"recovering {broken} into itself would destroy it; give another output path")
    report = RecoveryReport(messages={})
    end = StreamEnd()
    schema_ids: dict[int, int] = {0: 0}
    channels: dict[int, tuple[int, str]] = {}  # input channel id -> (output id, topic)
    fixed.parent.mkdir(parents=True, exist_ok=True)
    stream = _UnbufferedFile(fixed)
    writer = Writer(stream, chunk_size=chunk_size, compression=CompressionType.ZSTD)
    try:
        started = False
        for record in stream_records(broken, end):
            if isinstance(record, Header):
                writer.start(profile=record.profile, library=record.library or "zenslam recover")
                started = True
                continue
            if not started:
                writer.start(profile="", library="zenslam recover")
                started = True
            if isinstance(record, Schema) and record.id not in schema_ids:
                schema_ids[record.id] = writer.register_schema(record.name, record.encoding, record.data)
                report.schemas += 1
            elif isinstance(record, Channel) and record.id not in channels:
                new_id = writer.register_channel(record.topic, record.message_encoding, schema_ids.get(record.schema_id, 0), record.metadata)
                channels[record.id] = (new_id, record.topic)
                report.channels += 1
            elif isinstance(record, McapMessage) and record.channel_id in channels:
                new_id, topic = channels[record.channel_id]
                writer.add_message(new_id, record.log_time, record.data, record.publish_time, record.sequence)
                report.messages[topic] = report.messages.get(topic, 0) + 1
            elif isinstance(record, Attachment):
                writer.add_attachment(record.create_time, record.log_time, record.name, record.media_type, record.data)
                report.attachments += 1
            elif isinstance(record, Metadata):
                writer.add_metadata(record.name, record.metadata)
                report.metadata += 1
        if not started:
            writer.start(profile="", library="zenslam recover")
        writer.finish()
    finally:
        stream.close()
    report.complete, report.stop_reason = end.complete, end.reason
    return report
