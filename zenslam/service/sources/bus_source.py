"""Frames that another program publishes on the bus (``zenoh:<prefix>``), taken live, newest first.

``BusFrames.frames()`` subscribes to the keys of a message family (bus_messages.py) when it is first
iterated, and yields each frame as a codec.FrameMessage (the frame with its calibration and
sensor) when the consumer asks for the next one: the newest complete frame at that moment. Frames
that arrived while the consumer was busy are dropped (``dropped``): a tracker must keep up with the
camera rather than fall behind it. Each key keeps its ``pending`` newest messages (zenoh's callback
only appends the raw payload, bounded); the consumer's thread decodes.

Bad input never ends the stream: a payload over ``source.max_message_bytes`` (``oversized``) or one
that does not decode (``malformed``) is counted in ``rejected`` with the reasons of frame_assembly.py;
a frame whose stamp does not increase comes out as a SkippedFrame, as from a dataset.

The stream ends when the publishers' liveliness tokens (family.liveliness_key) have all gone and
nothing arrived for ``_END_QUIET_S``, when no frame arrived for ``source.idle_timeout_s`` after the
first one, when a zenslam frame stream sends its end of stream, or when ``should_stop()`` turns
true. Before the first frame: no message within ``source.first_frame_timeout_s`` is a BusError
naming the keys and endpoints; messages but no complete frame within ``source.calibration_timeout_s``
of the first image is a CalibrationError saying what is missing (usually the calibration: publish it
or give ``--orbslam-settings``).
"""

from __future__ import annotations

import dataclasses
import logging
import struct
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator
from contextlib import ExitStack

import cv2
from google.protobuf.message import DecodeError

from zenslam.errors import BusError, CalibrationError, MessageError, ZenslamError
from zenslam.runtime import bus
from zenslam.schemas import codec
from zenslam.service.sources.bus_messages import CALIBRATION_ROLES, MessageFamily, Role
from zenslam.service.sources.config import SourceConfig
from zenslam.service.sources.frame_assembly import FrameAssembler
from zenslam.service.sources.frame_stream import SkippedFrame, stamp_problem

logger = logging.getLogger(__name__)

_END_QUIET_S = 0.5  # seconds without a message, once the publishers' tokens are gone, before the stream ends
_WAITED_ON: frozenset[Role] = frozenset({"frame", "image", "left_image"})  # what CameraPublisher.wait_for_subscriber watches
# What decoding another program's payload may raise besides our own errors: protobuf, OpenCV and
# numpy/struct on truncated or inconsistent bytes. Each is a bad message, counted and dropped.
_BAD_PAYLOAD_ERRORS = (ZenslamError, DecodeError, ValueError, TypeError, OverflowError, struct.error, cv2.error)


def schema_of(encoding: bus.Encoding) -> str | None:
    """The schema of a zenoh encoding (``application/protobuf;foxglove.RawImage`` -> ``foxglove.RawImage``), or None."""
    _, _, schema = str(encoding).partition(";")
    return schema or None


class BusFrames:
    """The frames of ``family``'s keys on ``session`` (see the module docstring); ``clock``: seconds, monotonic."""

    def __init__(
        self,
        session: bus.Session,
        family: MessageFamily,
        config: SourceConfig,
        should_stop: Callable[[], bool],
        clock: Callable[[], float] = time.monotonic,
    ):
        self._session = session
        self._family = family
        self._config = config
        self._should_stop = should_stop
        self._clock = clock
        self._roles = family.subscriptions()
        keys_by_role = {role: key for key, role in self._roles.items()}
        self.assembler = FrameAssembler(
            family.name, keys_by_role, config.calibration, config.sensor, round(config.pair_tolerance_ms * 1e6)
        )
        self._lock = threading.Lock()
        self._pending: dict[str, deque[tuple[str, bytes, str | None]]] = {key: deque() for key in self._roles}
        self._evicted: Counter[Role] = Counter()  # messages pushed out of a full key before they were looked at
        self._oversized = 0
        self._messages = 0  # messages received on the family's keys
        self._tokens: set[str] = set()
        self._tokens_seen = False
        self._last_message_at: float | None = None
        self._ended = False  # a zenslam frame stream sent its end of stream
        self._first_image_at: float | None = None  # when the first image or frame arrived

    @property
    def dropped(self) -> int:
        """Frames passed over for a newer one (tracking was busy), so far."""
        primary = self._evicted["frame"] + self._evicted["image"] + self._evicted["left_image"]
        return self.assembler.dropped + primary

    @property
    def messages(self) -> int:
        """Messages received on the family's keys so far (read or not, usable or not)."""
        with self._lock:
            return self._messages

    @property
    def rejected(self) -> dict[str, int]:
        """Messages that could not be used, by reason, so far."""
        counts = Counter(self.assembler.rejected)
        if self._oversized:
            counts["oversized"] += self._oversized
        return dict(sorted(counts.items()))

    def frames(self) -> Iterator[codec.FrameMessage | SkippedFrame]:
        """Each frame the consumer asks for: the newest complete one (see the module docstring)."""
        with ExitStack() as stack:
            # The publishers' tokens are watched first, and the keys a publisher waits on (its images) are
            # declared last: once a publisher sees its images matched, every other key of the frame
            # (calibration, depth, right image) is matched too and its token's going will be seen,
            # however fast it publishes and leaves.
            stack.enter_context(bus.watch_tokens(self._session, self._family.liveliness_key(), self._on_token))
            for key, role in sorted(self._roles.items(), key=lambda item: item[1] in _WAITED_ON):
                stack.enter_context(bus.declare_callback_subscriber(self._session, key, self._receiver(key, role)))
            subscribed_at = self._clock()
            logger.info("%s: waiting for frames on %s", self._family.name, ", ".join(self._roles))
            previous: tuple[int, int] | None = None
            passed_on = 0
            while True:
                frame = self._next_frame(subscribed_at if previous is None else None)
                if frame is None:
                    return
                # Numbered as passed on, so the frontend sees no gap for a frame dropped here (counted in ``dropped``).
                frame = dataclasses.replace(frame, frame=dataclasses.replace(frame.frame, index=passed_on))
                passed_on += 1
                problem = None if previous is None else stamp_problem(frame.frame.index, frame.frame.stamp_ns, *previous)
                if problem is None:
                    previous = (frame.frame.index, frame.frame.stamp_ns)
                yield frame if problem is None else problem

    def _receiver(self, key: str, role: Role) -> Callable[[bus.Sample], None]:
        limit = self._config.max_message_bytes
        capacity = 1 if role in CALIBRATION_ROLES else self._config.pending

        def receive(sample: bus.Sample) -> None:
            # zenoh's thread: only checks the size and queues the bytes; decoding is the consumer's.
            now = self._clock()
            with self._lock:
                self._last_message_at = now
                self._messages += 1
                if len(sample.payload) > limit:
                    self._oversized += 1
                    return
                queue = self._pending[key]
                if len(queue) >= capacity:
                    queue.popleft()
                    if role not in CALIBRATION_ROLES:
                        self._evicted[role] += 1
                queue.append((str(sample.key_expr), sample.payload.to_bytes(), schema_of(sample.encoding)))

        return receive

    def _on_token(self, sample: bus.Sample) -> None:
        with self._lock:
            # A token that went before its arrival was seen still shows that a publisher was there and left.
            self._tokens_seen = True
            if bus.token_appeared(sample):
                self._tokens.add(str(sample.key_expr))
            else:
                self._tokens.discard(str(sample.key_expr))

    def _decode_pending(self) -> None:
        """Decode what has arrived, oldest first per key, into the assembler."""
        with self._lock:
            taken = {key: list(queue) for key, queue in self._pending.items() if queue}
            for key in taken:
                self._pending[key].clear()
        for key, messages in taken.items():
            role = self._roles[key]
            for sample_key, payload, schema in messages:
                try:
                    message = self._family.decode(role, sample_key, payload, schema)
                except _BAD_PAYLOAD_ERRORS as exc:
                    self._reject_payload(sample_key, exc)
                    continue
                if isinstance(message, codec.EndOfStream):
                    self._ended = True
                else:
                    self.assembler.add(role, message)

    def _reject_payload(self, key: str, exc: Exception) -> None:
        detail = str(exc) if isinstance(exc, ZenslamError) else f"{key}: {type(exc).__name__}: {exc}"
        if self._config.strict:
            raise MessageError(f"{detail} (source.strict: a bad message ends the run)") from exc
        self.assembler.reject("malformed", detail)

    def _next_frame(self, waiting_since: float | None) -> codec.FrameMessage | None:
        """The newest complete frame, waiting for one; None at the end of the stream.
        ``waiting_since``: when the wait for the first frame began (None after the first frame)."""
        pause = 0.0005
        while not self._should_stop():
            self._decode_pending()
            frame = self.assembler.take_newest()
            if frame is not None:
                return frame
            if self._stream_ended(waiting_since is None):
                return None
            if waiting_since is not None:
                self._check_first_frame(waiting_since)
            time.sleep(pause)
            pause = min(pause * 2.0, 0.005)
        return None

    def _stream_ended(self, started: bool) -> bool:
        now = self._clock()
        with self._lock:
            quiet_s = None if self._last_message_at is None else now - self._last_message_at
            tokens_gone = self._tokens_seen and not self._tokens
        if self._ended:
            logger.info("%s: the publisher ended its stream", self._family.name)
            return True
        if tokens_gone and (quiet_s is None or quiet_s > _END_QUIET_S):
            logger.info("%s: the publisher's liveliness token is gone: end of stream", self._family.name)
            return True
        idle_s = self._config.idle_timeout_s
        if started and idle_s > 0 and quiet_s is not None and quiet_s > idle_s:
            logger.info("%s: no message for %.1f s (source.idle_timeout_s): end of stream", self._family.name, quiet_s)
            return True
        return False

    def _check_first_frame(self, waiting_since: float) -> None:
        """Raise when the first frame is overdue: nothing arrived at all, or no complete frame."""
        now = self._clock()
        with self._lock:
            heard = self._last_message_at is not None
        first_s, calibration_s = self._config.first_frame_timeout_s, self._config.calibration_timeout_s
        if not heard and first_s > 0 and now - waiting_since > first_s:
            raise BusError(
                f"{self._family.name}: no message on {', '.join(self._roles)} within {first_s:.0f} s "
                f"(source.first_frame_timeout_s); is the publisher running, and reachable at "
                f"{', '.join(self._config.connect) or 'the bus configuration'} (--connect)?"
            )
        if self.assembler.received and self._first_image_at is None:
            self._first_image_at = now
        if self._first_image_at is not None and now - self._first_image_at > calibration_s:
            raise CalibrationError(f"{self._family.name}: no frame within {calibration_s:.0f} s of the first image: {self._missing()}")

    def _missing(self) -> str:
        """What the first frame still waits for, for people."""
        assembler = self.assembler
        keys = {role: key for key, role in self._roles.items()}
        if assembler.sensor is None:
            return "cannot tell a mono from an RGB-D camera yet; give --sensor"
        calibration_keys = ("left_calibration", "right_calibration") if assembler.sensor == "stereo" else ("calibration",)
        if not assembler.camera_known():
            problem = f" ({assembler.calibration_problem})" if assembler.calibration_problem else ""
            return (
                f"no usable calibration on {' and '.join(keys[role] for role in calibration_keys)}{problem}; publish "
                "foxglove.CameraCalibration messages there, or give the camera with --orbslam-settings"
            )
        partner = "right_image" if assembler.sensor == "stereo" else "depth"
        return f"the images found no {keys[partner]} message stamped within {self._config.pair_tolerance_ms:g} ms (source.pair_tolerance_ms)"
