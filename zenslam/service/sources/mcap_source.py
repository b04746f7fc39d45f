"""Frames replayed from a zenslam recording: the sensor/frame channel of a run.mcap as a Source.

Every recorded zenslam.SensorFrame carries its calibration, sensor kind and source name, so the
recording alone is enough to play it again. A first pass reads the channel once for the stamps,
calibration and count (the images are decoded lazily, again, when iterated). The ground truth is
the one the recorded run's source had (its /source/ground_truth channel; None in recordings made
before that channel existed). The recorder has no IMU channel, so imu() is None.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import CalibrationError, DatasetError, TimestampError
from zenslam.schemas import codec, keys
from zenslam.service import mcap_io
from zenslam.service.recorded_ground_truth import read_ground_truth, write_ground_truth
from zenslam.service.sources.frame import ImuSamples, SensorFrame, check_frame_index
from zenslam.trajectory import Trajectory

logger = logging.getLogger(__name__)

_ANY_SESSION = "replay"


def sensor_frame_topic() -> str:
    """The MCAP topic of the sensor/frame key (``/sensor/frame``)."""
    return mcap_io.topic_for_key(keys.sensor_frame(_ANY_SESSION), _ANY_SESSION)


class McapSource:
    """The recorded sensor frames of ``path`` in recorded order (spec ``mcap:<file>``)."""

    def __init__(self, path: str | Path):
        self.path = Path(path).expanduser()
        self._topic = sensor_frame_topic()
        stamps: list[int] = []
        first: codec.FrameMessage | None = None
        for decoded in self._decoded():
            frame = decoded.frame
            if first is None:
                first = decoded
            elif (decoded.calibration, decoded.sensor) != (first.calibration, first.sensor):
                raise CalibrationError(
                    f"{self.path}: frame {frame.index} is {decoded.sensor} with {decoded.calibration.summary()}, but the "
                    f"first frame is {first.sensor} with {first.calibration.summary()}; a source has one camera"
                )
            if stamps and frame.stamp_ns <= stamps[-1]:
                raise TimestampError(
                    f"{self.path}: frame {frame.index} has stamp {frame.stamp_ns} ns, not after the previous "
                    f"{stamps[-1]} ns; the recording's {self._topic} channel is out of order"
                )
            stamps.append(frame.stamp_ns)
        if first is None:
            raise DatasetError(
                f"{self.path} has no frames on {self._topic}; replay needs a recording made by `zenslam run` "
                "with the recorder enabled"
            )
        self._stamps_ns = np.array(stamps, dtype=np.int64)
        self._calibration = first.calibration
        self._sensor: SensorKind = first.sensor
        self._name = first.source_name or self.path.stem
        self._cursor: Iterator[codec.FrameMessage] | None = None  # frame(): the recorded frames from _cursor_next on
        self._cursor_next = 0
        logger.info("%s: %d %s frames of %r", self.path, len(stamps), self._sensor, self._name)

    def _decoded(self) -> Iterator[codec.FrameMessage]:
        # File order is the order the source published in (one key, one publisher); end-of-stream skipped.
        for message in mcap_io.iter_messages(self.path, [self._topic], log_time_order=False):
            decoded = codec.decode_sensor_frame(message.data)
            if isinstance(decoded, codec.FrameMessage):
                yield decoded

    @property
    def name(self) -> str:
        """The recorded source's name (what it put in each frame), so a replay re-sends identical frames."""
        return self._name

    @property
    def sensor(self) -> SensorKind:
        return self._sensor

    @property
    def calibration(self) -> PinholeCalibration:
        return self._calibration

    def __len__(self) -> int:
        return len(self._stamps_ns)

    def __iter__(self) -> Iterator[SensorFrame]:
        for decoded in self._decoded():
            yield decoded.frame

    def frame(self, index: int) -> SensorFrame:
        """The ``index``-th recorded frame (its ``index`` field is the one recorded). Reads on from the
        last frame asked for; asking for an earlier one reads the file again from its start."""
        check_frame_index(self.name, index, len(self))
        if self._cursor is None or index < self._cursor_next:
            self._cursor, self._cursor_next = self._decoded(), 0
        for decoded in self._cursor:
            self._cursor_next += 1
            if self._cursor_next == index + 1:
                return decoded.frame
        raise DatasetError(f"{self.path} ended before frame {index} of {len(self)}; was it changed while being read?")

    def stamps_ns(self) -> np.ndarray:
        """All frame stamps (N,) int64, in recorded order."""
        return self._stamps_ns.copy()

    def ground_truth(self) -> Trajectory | None:
        """The recorded source's ground truth, or None when the recording holds none."""
        return read_ground_truth(self.path)

    def imu(self) -> ImuSamples | None:
        """None: the recorder has no IMU channel."""
        return None


def write_frames(
    path: str | Path,
    frames: Iterable[SensorFrame],
    calibration: PinholeCalibration,
    sensor: SensorKind,
    source_name: str = "",
    ground_truth: Trajectory | None = None,
) -> int:
    """Record ``frames`` on the sensor/frame channel of a new MCAP file as the recorder would (PNG images,
    log time = stamp, ns), ending with the stream's end-of-stream message, after ``ground_truth`` if
    given; returns the frames written."""
    topic = sensor_frame_topic()
    written, last_stamp_ns = 0, 0
    with mcap_io.RecordingWriter(path) as writer:
        if ground_truth is not None:
            write_ground_truth(writer, ground_truth)
        for frame in frames:
            data = codec.encode_sensor_frame(frame, calibration, sensor, source_name, image_encoding="png")
            writer.write(topic, codec.SENSOR_FRAME, data, frame.stamp_ns)
            written, last_stamp_ns = written + 1, frame.stamp_ns
        writer.write(topic, codec.SENSOR_FRAME, codec.encode_end_of_stream(codec.SENSOR_FRAME, written), last_stamp_ns)
    return written
