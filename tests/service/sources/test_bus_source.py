"""BusFrames over a real zenoh session: frames from foxglove or zenslam messages, bad input counted and
dropped (a fuzz of thousands of payloads on every key), the end of stream, and the missing-calibration error."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
import pytest
import zenoh

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError
from zenslam.runtime import bus
from zenslam.schemas import codec
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.service.bus_publisher import CameraPublisher
from zenslam.service.sources.bus_source import BusFrames
from zenslam.service.sources.config import SourceConfig
from zenslam.service.sources.frame_stream import SkippedFrame
from zenslam.service.sources.zenoh_family import ZenohFamily

CAMERA = PinholeCalibration(40.0, 40.0, 15.5, 11.5, 32, 24, 0.15)
DEADLINE_S = 60.0
VALID_STAMP_NS = 1 << 62  # after any stamp a mutated message is likely to carry


def wait_until(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + DEADLINE_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.005)


class Consumer:
    """Iterates BusFrames.frames() on a thread, keeping what it yields and what it raised."""

    def __init__(self, session: zenoh.Session, prefix: str, config: SourceConfig):
        self.stop = threading.Event()
        self.frames = BusFrames(session, ZenohFamily(prefix), config, self.stop.is_set)
        self.items: list[codec.FrameMessage | SkippedFrame] = []
        self.error: Exception | None = None
        self.done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            for item in self.frames.frames():
                self.items.append(item)
        except Exception as exc:  # noqa: BLE001 - handed to the test, which asserts on it
            self.error = exc
        finally:
            self.done.set()

    def close(self) -> None:
        self.stop.set()
        self._thread.join(DEADLINE_S)


@pytest.fixture
def session():
    with bus.open_session(bus.BusConfig()) as opened:
        yield opened


def frame(k: int, sensor: str, rng: np.random.Generator) -> SensorFrame:
    left = rng.integers(0, 256, (24, 32), dtype=np.uint8)
    right = rng.integers(0, 256, (24, 32), dtype=np.uint8) if sensor == "stereo" else None
    depth = rng.uniform(0.5, 4.0, (24, 32)).astype(np.float32) if sensor == "rgbd" else None
    return SensorFrame(k, VALID_STAMP_NS + k * 100_000_000, left, right, depth)


def mutations(valid: bytes, count: int, rng: np.random.Generator) -> list[bytes]:
    """Random bytes, truncations, bit flips, insertions and deletions of ``valid``."""
    out = []
    for n in range(count):
        kind = n % 5
        data = bytearray(valid)
        if kind == 0:
            data = bytearray(rng.integers(0, 256, int(rng.integers(0, 300)), dtype=np.uint8).tobytes())
        elif kind == 1:
            data = data[: int(rng.integers(0, len(data)))]
        elif kind == 2:
            for at in rng.integers(0, len(data), int(rng.integers(1, 8))):
                data[at] ^= 1 << int(rng.integers(0, 8))
        elif kind == 3:
            at = int(rng.integers(0, len(data)))
            data[at:at] = rng.integers(0, 256, int(rng.integers(1, 16)), dtype=np.uint8).tobytes()
        else:
            at = int(rng.integers(0, len(data)))
            del data[at : at + int(rng.integers(1, 32))]
        out.append(bytes(data))
    return out


LAYOUTS = [("stereo", "foxglove", "raw"), ("rgbd", "foxglove", "png"), ("stereo", "zenslam", "raw")]


@pytest.mark.parametrize("sensor,fmt,image_format", LAYOUTS)
def test_fuzzed_payloads_on_every_key_are_counted_and_dropped(session, sensor, fmt, image_format):
    rng = np.random.default_rng(11)
    prefix = f"fuzz/{sensor}/{fmt}"
    config = SourceConfig(pending=100_000, max_message_bytes=20_000, idle_timeout_s=0, calibration_timeout_s=DEADLINE_S)
    per_key = 1500
    with CameraPublisher(session, prefix, sensor, fmt, image_format) as camera:
        consumer = Consumer(session, prefix, config)
        try:
            assert camera.wait_for_subscriber(lambda: consumer.done.is_set())
            first = frame(0, sensor, rng)
            camera.publish(first, CAMERA)  # the stream starts well: its camera is fixed by this frame
            wait_until(lambda: _yielded(consumer, first.stamp_ns), "the first frame")
            # Each key's valid message is the seed of its mutations.
            sent = camera.messages(first, CAMERA)
            oversized = 0
            for key, valid in sent.items():
                publisher = session.declare_publisher(key)
                for payload in mutations(valid, per_key, rng):
                    publisher.put(payload)
                for _ in range(3):
                    publisher.put(b"\0" * 25_000)
                    oversized += 1
            # Then good frames, each waited for: the source still works after the garbage.
            for k in range(1, 4):
                good = frame(k, sensor, rng)
                before = len(consumer.items)
                camera.publish(good, CAMERA)
                wait_until(lambda good=good: _yielded(consumer, good.stamp_ns), f"frame {k}")
                assert len(consumer.items) > before
                last = consumer.items[-1]
                if isinstance(last, codec.FrameMessage):
                    np.testing.assert_array_equal(last.frame.left, good.left)
        finally:
            consumer.close()
    assert consumer.error is None
    rejected = consumer.frames.rejected
    assert rejected.get("oversized") == oversized
    assert rejected.get("malformed", 0) > 0.3 * per_key * len(sent)  # many mutations do not decode; each is counted


def _yielded(consumer: Consumer, stamp_ns: int) -> bool:
    assert consumer.error is None, consumer.error
    for item in consumer.items[-3:]:
        if isinstance(item, codec.FrameMessage) and item.frame.stamp_ns == stamp_ns:
            return True
        if isinstance(item, SkippedFrame) and str(stamp_ns) in str(item.error):
            return True  # a mutated stamp later than ours came first: ours is skipped as going backwards
    return False


def test_frames_come_newest_first_and_the_stream_ends_with_the_publishers_token(session):
    rng = np.random.default_rng(5)
    published = [frame(k, "stereo", rng) for k in range(6)]
    with CameraPublisher(session, "cam/a", "stereo", "foxglove", "raw") as camera:
        stop = threading.Event()
        frames = BusFrames(session, ZenohFamily("cam/a"), SourceConfig(idle_timeout_s=0), stop.is_set)
        iterator = frames.frames()
        thread = threading.Thread(target=lambda: camera.wait_for_subscriber(stop.is_set) and camera.publish(published[0], CAMERA))
        thread.start()
        first = next(iterator)  # subscribes, then waits for the first complete frame
        thread.join()
        assert first.sensor == "stereo" and first.calibration == CAMERA and first.frame.stamp_ns == published[0].stamp_ns
        for later in published[1:]:  # five frames while the consumer is busy
            camera.publish(later, CAMERA)
        wait_until(lambda: frames.messages == 4 * len(published), "every message")
        newest = next(iterator)
        assert newest.frame.stamp_ns == published[-1].stamp_ns and newest.frame.index == 1  # numbered as passed on
        np.testing.assert_array_equal(newest.frame.right, published[-1].right)
        assert frames.dropped == 4 and frames.rejected == {}
    # The publisher's liveliness token is gone: the stream ends.
    assert list(iterator) == []


def test_no_calibration_is_an_error_naming_the_keys_and_orbslam_settings(session):
    rng = np.random.default_rng(2)
    config = SourceConfig(calibration_timeout_s=0.3, idle_timeout_s=0)
    consumer = Consumer(session, "cam/b", config)
    try:
        left = session.declare_publisher("cam/b/left/image")
        right = session.declare_publisher("cam/b/right/image")
        wait_until(lambda: left.matching_status.matching, "the source's subscription")
        from zenslam.service.sources import foxglove_images as fox

        k = 0
        while not consumer.done.is_set():  # images keep coming, as from a camera without camera_info
            image = frame(k, "stereo", rng)
            right.put(fox.encode_raw_image(image.stamp_ns, image.right, "r"))
            left.put(fox.encode_raw_image(image.stamp_ns, image.left, "l"))
            k += 1
            wait_until(lambda k=k: consumer.done.is_set() or consumer.frames.assembler.received >= k, "the image")
    finally:
        consumer.close()
    assert isinstance(consumer.error, CalibrationError)
    message = str(consumer.error)
    assert "cam/b/left/calibration" in message and "cam/b/right/calibration" in message and "--orbslam-settings" in message
