"""Replay comparisons: what two recordings said on the deterministic topics, exactly or within a tolerance.

A lockstep run is deterministic, so a replay of its recording must publish the same messages:
``compare_recordings`` compares, topic by topic in recorded (publication) order, the messages of
frontend/pose, frontend/state, frontend/keyframe and backend/map_update, field by field and
element by element (``field_comparison``), and reports the message counts and the earliest
difference (topic, message index, stamp, the value's path and both values) or none. Measured
wall-clock durations (frontend/state ``timings_ms``) and the status topics are left out. With a
tolerance (for replays on another architecture, where bits cannot match), floating-point values
within it agree and the largest such deviation is reported instead. ``backend_replay`` runs the
backend alone on a recording's keyframes and compares with ``compare_streams``.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from zenslam.schemas import codec, keys
from zenslam.service import field_comparison, mcap_io
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
LOOP_TOPIC = _topic(keys.backend_loop)
COMPARED_TOPICS = (POSE_TOPIC, STATE_TOPIC, KEYFRAME_TOPIC, MAP_UPDATE_TOPIC, LOOP_TOPIC)
# Fields holding measured wall-clock durations: they differ between any two runs, so they are not compared.
IGNORED_FIELDS: dict[str, tuple[str, ...]] = {codec.TRACKING_STATE: ("timings_ms",)}


@dataclass(frozen=True)
class Difference:
    """A place where two message streams disagree (or, within tolerance, deviate)."""

    topic: str
    index: int  # position of the message in the topic, recorded order, 0-based
    stamp_ns: int  # the message's log time: its stamp (the last stamp seen, for an end of stream)
    field: str  # path of the value, e.g. "keyframes[2].T_world_cam.tx", "p_world[4][1]"; "message" when one side has none
    expected: str  # the recorded value
    actual: str  # the replayed value

    def describe(self) -> str:
        """One line for people."""
        return (
            f"{self.topic} message {self.index} (stamp_ns {self.stamp_ns}): {self.field}: "
            f"recorded {self.expected}, replayed {self.actual}"
        )


@dataclass(frozen=True)
class Comparison:
    """Message counts per compared topic, (recorded, replayed), the earliest difference beyond the
    tolerance if any, and (with a tolerance) the largest deviation within it."""

    counts: dict[str, tuple[int, int]] = field(default_factory=dict)
    difference: Difference | None = None
    tolerance: float | None = None  # None: bit-exact comparison
    largest: Difference | None = None  # the largest deviation within tolerance
    largest_scaled: float = 0.0  # its |recorded - replayed| / max(1, |recorded|)

    @property
    def identical(self) -> bool:
        """Every compared value has the same bits."""
        return self.difference is None and self.largest is None

    @property
    def equivalent(self) -> bool:
        """No difference beyond the tolerance (identical when there is none)."""
        return self.difference is None

    def lines(self) -> list[str]:
        """The verdict ("identical", "equivalent within X ..." or the first difference), then the counts per topic."""
        if self.identical:
            verdict = "identical"
        elif self.difference is None:
            verdict = (
                f"equivalent within {self.tolerance:g}: largest deviation {self.largest_scaled:.3g} "
                f"at {self.largest.describe()}"
            )
        else:
            beyond = "" if self.tolerance is None else f" beyond {self.tolerance:g}"
            verdict = f"first difference{beyond}: {self.difference.describe()}"
        return [verdict] + [f"  {topic}: {a} recorded, {b} replayed" for topic, (a, b) in self.counts.items()]


def compare_encoded(
    schema: str, expected: bytes, actual: bytes, tolerance: float | None = None
) -> field_comparison.MessageComparison:
    """How two encoded messages of ``schema`` compare (``field_comparison.compare_messages``), ignoring
    the measured fields of IGNORED_FIELDS; an unknown schema is compared byte by byte."""
    if expected == actual:
        return field_comparison.MessageComparison()
    cls = mcap_io.SCHEMA_CLASSES.get(schema)
    if cls is None:
        return field_comparison.MessageComparison(field_comparison.bytes_difference("bytes", expected, actual))
    a, b = cls.FromString(expected), cls.FromString(actual)
    for name in IGNORED_FIELDS.get(schema, ()):
        a.ClearField(name)
        b.ClearField(name)
    return field_comparison.compare_messages(a, b, tolerance)


def compare_streams(
    topic: str,
    expected: Sequence[mcap_io.RecordedMessage],
    actual: Sequence[mcap_io.RecordedMessage],
    tolerance: float | None = None,
) -> Comparison:
    """The counts, the first difference beyond ``tolerance`` and the largest deviation within it between
    two streams of one topic, message by message in order."""
    counts = {topic: (len(expected), len(actual))}
    largest: tuple[float, Difference] | None = None
    difference: Difference | None = None
    for index, (a, b) in enumerate(zip(expected, actual)):
        if a.schema != b.schema:
            difference = Difference(topic, index, a.log_time_ns, "schema", a.schema, b.schema)
            break
        found = compare_encoded(a.schema, a.data, b.data, tolerance)
        if found.largest is not None and (largest is None or found.largest.scaled > largest[0]):
            d = found.largest.difference
            largest = (found.largest.scaled, Difference(topic, index, a.log_time_ns, d.path, d.recorded, d.replayed))
        if found.difference is not None:
            d = found.difference
            difference = Difference(topic, index, a.log_time_ns, d.path, d.recorded, d.replayed)
            break
    if difference is None and len(expected) != len(actual):
        index = min(len(expected), len(actual))
        longer = expected if len(expected) > len(actual) else actual
        present = f"a {longer[index].schema} message"
        recorded, replayed = (present, "none") if longer is expected else ("none", present)
        difference = Difference(topic, index, longer[index].log_time_ns, "message", recorded, replayed)
    scaled, where = largest if largest is not None else (0.0, None)
    return Comparison(counts, difference, tolerance, where, scaled)


def read_topics(path: str | Path, topics: Iterable[str]) -> dict[str, list[mcap_io.RecordedMessage]]:
    """The messages of ``topics`` in ``path``, per topic in file (publication) order, in one pass."""
    streams: dict[str, list[mcap_io.RecordedMessage]] = {topic: [] for topic in topics}
    for message in mcap_io.iter_messages(path, streams, log_time_order=False):
        streams[message.topic].append(message)
    return streams


def merge(comparisons: Sequence[Comparison], order: Sequence[str]) -> Comparison:
    """One comparison of several topics: all counts, the earliest difference (by stamp, then topic in
    ``order``, then index) and the largest deviation."""
    counts = {topic: c.counts[topic] for c in comparisons for topic in c.counts}
    differences = [c.difference for c in comparisons if c.difference is not None]
    earliest = min(differences, key=lambda d: (d.stamp_ns, order.index(d.topic), d.index)) if differences else None
    deviating = [c for c in comparisons if c.largest is not None]
    largest = max(deviating, key=lambda c: c.largest_scaled) if deviating else Comparison()
    tolerance = comparisons[0].tolerance if comparisons else None
    return Comparison(counts, earliest, tolerance, largest.largest, largest.largest_scaled)


def compare_recordings(
    recorded: str | Path, replayed: str | Path, topics: Sequence[str] = COMPARED_TOPICS, tolerance: float | None = None
) -> Comparison:
    """Counts, the earliest (by stamp) difference beyond ``tolerance`` and the largest deviation within
    it between two recordings on ``topics``."""
    expected, actual = read_topics(recorded, topics), read_topics(replayed, topics)
    return merge([compare_streams(t, expected[t], actual[t], tolerance) for t in topics], topics)


def recorded_run_config(recording: str | Path) -> RunConfig:
    """The configuration the recording was made with: the ``config.yaml`` beside it, or the defaults
    (with a warning) when there is none."""
    path = Path(recording).parent / CONFIG_FILENAME
    if not path.is_file():
        logger.warning("no %s beside %s: replaying with the default configuration", CONFIG_FILENAME, recording)
        return RunConfig()
    return load_run_config(path)
