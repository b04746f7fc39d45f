"""Replay comparisons: what two recordings (or a recording and a fresh backend) said on the deterministic topics.

A lockstep run is deterministic, so a replay of its recording must publish the same messages:
``compare_recordings`` compares, topic by topic in recorded (publication) order, the messages of
frontend/pose, frontend/state, frontend/keyframe and backend/map_update, field by field, and reports
the message counts and the earliest difference (topic, message index, stamp, protobuf field path)
or none. Measured wall-clock durations (frontend/state ``timings_ms``) and the status topics are
left out. ``replay_backend`` feeds the recorded keyframes to a fresh ``BackendNode`` in this
process and compares its map updates with the recorded ones.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from google.protobuf.message import Message

from zenslam.backend.config import BackendConfig
from zenslam.backend.node import BackendNode
from zenslam.schemas import codec, keys
from zenslam.service import mcap_io
from zenslam.service.run_config import RunConfig, load_run_config
from zenslam.service.run_output import CONFIG_FILENAME

logger = logging.getLogger(__name__)

_ANY_SESSION = "replay"


def _topic(key_of_session) -> str:
    return mcap_io.topic_for_key(key_of_session(_ANY_SESSION), _ANY_SESSION)


POSE_TOPIC = _topic(keys.frontend_pose)
STATE_TOPIC = _topic(keys.frontend_state)
KEYFRAME_TOPIC = _topic(keys.frontend_keyframe)
MAP_UPDATE_TOPIC = _topic(keys.backend_map_update)
COMPARED_TOPICS = (POSE_TOPIC, STATE_TOPIC, KEYFRAME_TOPIC, MAP_UPDATE_TOPIC)
# Fields holding measured wall-clock durations: they differ between any two runs, so they are not compared.
IGNORED_FIELDS: dict[str, tuple[str, ...]] = {codec.TRACKING_STATE: ("timings_ms",)}
_SHOWN_CHARS = 60  # characters of a differing value shown in a report


@dataclass(frozen=True)
class Difference:
    """The first place two message streams disagree."""

    topic: str
    index: int  # position of the message in the topic, recorded order, 0-based
    stamp_ns: int  # the message's log time: its stamp (the last stamp seen, for an end of stream)
    field: str  # protobuf field path, e.g. "keyframes[2].T_world_cam.tx"; "message" when one side has none
    expected: str  # the recorded value, shortened
    actual: str  # the replayed value, shortened

    def describe(self) -> str:
        """One line for people."""
        return (
            f"{self.topic} message {self.index} (stamp_ns {self.stamp_ns}): {self.field}: "
            f"recorded {self.expected}, replayed {self.actual}"
        )


@dataclass(frozen=True)
class Comparison:
    """Message counts per compared topic, (recorded, replayed), and the earliest difference if any."""

    counts: dict[str, tuple[int, int]] = field(default_factory=dict)
    difference: Difference | None = None

    @property
    def identical(self) -> bool:
        return self.difference is None

    def lines(self) -> list[str]:
        """The verdict ("identical" or the first difference), then the counts per topic."""
        verdict = "identical" if self.identical else f"first difference: {self.difference.describe()}"
        return [verdict] + [f"  {topic}: {a} recorded, {b} replayed" for topic, (a, b) in self.counts.items()]


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= _SHOWN_CHARS else text[: _SHOWN_CHARS - 3] + "..."


def _same_scalar(a: object, b: object) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return (a == b and math.copysign(1.0, a) == math.copysign(1.0, b)) or (math.isnan(a) and math.isnan(b))
    return a == b


def _bytes_difference(path: str, a: bytes, b: bytes) -> tuple[str, str, str] | None:
    if a == b:
        return None
    offset = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
    return f"{path} (byte {offset})", f"{len(a)} bytes", f"{len(b)} bytes"


def _repeated_difference(path: str, fd, a: Sequence, b: Sequence) -> tuple[str, str, str] | None:
    for i, (x, y) in enumerate(zip(a, b)):
        if fd.message_type is not None:
            found = field_difference(x, y, f"{path}[{i}].")
        else:
            found = None if _same_scalar(x, y) else (f"{path}[{i}]", _short(x), _short(y))
        if found is not None:
            return found
    if len(a) != len(b):
        return f"{path} length", str(len(a)), str(len(b))
    return None


def field_difference(a: Message, b: Message, prefix: str = "") -> tuple[str, str, str] | None:
    """(field path, a's value, b's value) of the first field, in field-number order, where two messages of
    one type differ; None when they are equal field by field (maps compared as dictionaries)."""
    for fd in sorted(a.DESCRIPTOR.fields, key=lambda f: f.number):
        path = prefix + fd.name
        va, vb = getattr(a, fd.name), getattr(b, fd.name)
        if fd.message_type is not None and fd.message_type.GetOptions().map_entry:
            da, db = dict(va), dict(vb)
            for key in sorted(set(da) | set(db)):
                if key not in da or key not in db or not _same_scalar(da[key], db[key]):
                    return f"{path}[{key!r}]", _short(da.get(key, "absent")), _short(db.get(key, "absent"))
        elif fd.is_repeated:
            found = _repeated_difference(path, fd, va, vb)
            if found is not None:
                return found
        elif fd.message_type is not None:
            if fd.has_presence and a.HasField(fd.name) != b.HasField(fd.name):
                return path, "set" if a.HasField(fd.name) else "unset", "set" if b.HasField(fd.name) else "unset"
            found = field_difference(va, vb, path + ".")
            if found is not None:
                return found
        elif fd.type == fd.TYPE_BYTES:
            found = _bytes_difference(path, va, vb)
            if found is not None:
                return found
        elif not _same_scalar(va, vb) or (fd.has_presence and a.HasField(fd.name) != b.HasField(fd.name)):
            return path, _short(va), _short(vb)
    return None


def message_difference(schema: str, expected: bytes, actual: bytes) -> tuple[str, str, str] | None:
    """Where two encoded messages of ``schema`` differ (field path, expected, actual), ignoring the
    measured fields of IGNORED_FIELDS; None when they agree."""
    if expected == actual:
        return None
    cls = mcap_io.SCHEMA_CLASSES.get(schema)
    if cls is None:
        return _bytes_difference("<undecoded bytes>", expected, actual)
    a, b = cls.FromString(expected), cls.FromString(actual)
    for name in IGNORED_FIELDS.get(schema, ()):
        a.ClearField(name)
        b.ClearField(name)
    return field_difference(a, b)


def compare_streams(
    topic: str, expected: Sequence[mcap_io.RecordedMessage], actual: Sequence[mcap_io.RecordedMessage]
) -> Difference | None:
    """The first difference between two streams of one topic, message by message in order; None if equal."""
    for index, (a, b) in enumerate(zip(expected, actual)):
        if a.schema != b.schema:
            return Difference(topic, index, a.log_time_ns, "schema", a.schema, b.schema)
        found = message_difference(a.schema, a.data, b.data)
        if found is not None:
            return Difference(topic, index, a.log_time_ns, *found)
    if len(expected) != len(actual):
        index = min(len(expected), len(actual))
        longer = expected if len(expected) > len(actual) else actual
        present = f"a {longer[index].schema} message"
        recorded, replayed = (present, "none") if longer is expected else ("none", present)
        return Difference(topic, index, longer[index].log_time_ns, "message", recorded, replayed)
    return None


def read_topics(path: str | Path, topics: Iterable[str]) -> dict[str, list[mcap_io.RecordedMessage]]:
    """The messages of ``topics`` in ``path``, per topic in file (publication) order, in one pass."""
    streams: dict[str, list[mcap_io.RecordedMessage]] = {topic: [] for topic in topics}
    for message in mcap_io.iter_messages(path, streams, log_time_order=False):
        streams[message.topic].append(message)
    return streams


def _earliest(differences: Iterable[Difference], order: Sequence[str]) -> Difference | None:
    found = list(differences)
    return min(found, key=lambda d: (d.stamp_ns, order.index(d.topic), d.index)) if found else None


def compare_recordings(recorded: str | Path, replayed: str | Path, topics: Sequence[str] = COMPARED_TOPICS) -> Comparison:
    """Counts and the earliest (by stamp) difference between two recordings on ``topics``."""
    expected, actual = read_topics(recorded, topics), read_topics(replayed, topics)
    counts = {topic: (len(expected[topic]), len(actual[topic])) for topic in topics}
    differences = (compare_streams(t, expected[t], actual[t]) for t in topics)
    return Comparison(counts, _earliest((d for d in differences if d is not None), topics))


def recorded_run_config(recording: str | Path) -> RunConfig:
    """The configuration the recording was made with: the ``config.yaml`` beside it, or the defaults
    (with a warning) when there is none."""
    path = Path(recording).parent / CONFIG_FILENAME
    if not path.is_file():
        logger.warning("no %s beside %s: replaying with the default configuration", CONFIG_FILENAME, recording)
        return RunConfig()
    return load_run_config(path)


def replay_backend(recording: str | Path, config: BackendConfig) -> Comparison:
    """Feed the recorded frontend/keyframe messages, in order, to a fresh backend built from ``config``
    (in this process: ``BackendNode.step`` is deterministic) and compare its map updates, and the
    end of stream after them, with the recorded backend/map_update messages."""
    streams = read_topics(recording, (KEYFRAME_TOPIC, MAP_UPDATE_TOPIC))
    node = BackendNode.from_config(config)
    replayed: list[mcap_io.RecordedMessage] = []
    last_stamp_ns = 0
    for message in streams[KEYFRAME_TOPIC]:
        keyframe = codec.decode_keyframe(message.data)
        if isinstance(keyframe, codec.EndOfStream):
            data = codec.encode_end_of_stream(codec.MAP_UPDATE, node.processed)
            replayed.append(mcap_io.RecordedMessage(MAP_UPDATE_TOPIC, codec.MAP_UPDATE, last_stamp_ns, last_stamp_ns, 0, data))
            break
        update = node.step(keyframe)
        last_stamp_ns = max(last_stamp_ns, update.stamp_ns)
        data = codec.encode_map_update(update)
        replayed.append(mcap_io.RecordedMessage(MAP_UPDATE_TOPIC, codec.MAP_UPDATE, update.stamp_ns, update.stamp_ns, 0, data))
        logger.debug("keyframe %d replayed through the backend", keyframe.id)
    recorded = streams[MAP_UPDATE_TOPIC]
    counts = {MAP_UPDATE_TOPIC: (len(recorded), len(replayed))}
    return Comparison(counts, compare_streams(MAP_UPDATE_TOPIC, recorded, replayed))
