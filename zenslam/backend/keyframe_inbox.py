"""The backend's keyframe inbox: frontend/keyframe messages, lossless and bounded, each kept with the
bytes it arrived as (what the journal writes), and what waits in it behind the keyframe being mapped."""

from __future__ import annotations


from zenslam.runtime import bus
from zenslam.schemas import codec, keys

Received = tuple[bytes, codec.KeyframeMessage | codec.EndOfStream]  # the bytes as received, decoded


def subscribe_keyframes(session: bus.Session, session_name: str, capacity: int) -> bus.Inbox[Received]:
    """The frontend's keyframes and its end of stream, up to ``capacity`` messages waiting."""
    # Lossless and bounded: a full inbox blocks the frontend's send; no keyframe is ever dropped.
    return bus.subscribe(session, keys.frontend_keyframe(session_name), decode_keeping_bytes, "lossless", capacity)


def decode_keeping_bytes(payload: bytes) -> Received:
    """A frontend/keyframe message decoded, with its bytes as received (what the journal keeps)."""
    return payload, codec.decode_keyframe(payload)


def newer_keyframes_waiting(inbox: bus.Inbox[Received], keyframe_id: int) -> int:
    """Distinct keyframes after ``keyframe_id`` waiting in the inbox: the end of stream is none, nor
    is a keyframe a frontend sent again to this restarted backend (its copies would defer local
    mapping as a backlog does, and the map would no longer be the unharmed run's)."""
    newer: set[int] = set()

    def is_newer(received: Received) -> bool:
        message = received[1]
        if isinstance(message, codec.EndOfStream) or message.id <= keyframe_id or message.id in newer:
            return False
        newer.add(int(message.id))
        return True

    return inbox.count_waiting(is_newer)


def keyframes_waiting(inbox: bus.Inbox[Received]) -> list[codec.KeyframeMessage]:
    """The keyframes waiting in the inbox, oldest first, left in place (the end of stream is none)."""
    return [message for _, message in inbox.waiting() if not isinstance(message, codec.EndOfStream)]


def count_keyframes_waiting(inbox: bus.Inbox[Received]) -> int:
    """How many keyframes wait in the inbox (a lower bound, as ``Inbox.depth``; the end of stream is none)."""
    return inbox.count_waiting(_is_keyframe)


def _is_keyframe(received: Received) -> bool:
    return not isinstance(received[1], codec.EndOfStream)
