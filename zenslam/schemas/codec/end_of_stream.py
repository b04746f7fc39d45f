"""The last message of a stream (sensor frames, tracking states, keyframes, map updates)."""

from __future__ import annotations

from dataclasses import dataclass

from zenslam.errors import MessageError
from zenslam.schemas.codec.message_types import KEYFRAME, MAP_UPDATE, MESSAGE_CLASSES, SENSOR_FRAME, TRACKING_STATE


@dataclass(frozen=True)
class EndOfStream:
    """The last message of a stream; ``count`` data messages were sent before it."""

    count: int


_STREAMS = (SENSOR_FRAME, TRACKING_STATE, KEYFRAME, MAP_UPDATE)


def encode_end_of_stream(schema: str, count: int) -> bytes:
    """The end-of-stream message of the stream whose schema is one of SENSOR_FRAME, TRACKING_STATE,
    KEYFRAME or MAP_UPDATE."""
    if schema not in _STREAMS:
        raise MessageError(f"streams of {schema!r} have no end-of-stream message; use one of {list(_STREAMS)}")
    return MESSAGE_CLASSES[schema](end_of_stream=True, count=count).SerializeToString()
