"""The Source protocol: what every dataset reader and scene implements (frames are schemas.sensor_data)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Protocol

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import DatasetError, FrameReadError, ImageReadError
from zenslam.schemas.sensor_data import ImuSamples, SensorFrame
from zenslam.trajectory import Trajectory

__all__ = ["ImuSamples", "SensorFrame", "Source", "check_frame_index", "reading_frame"]


class Source(Protocol):
    """A dataset or scene that lazily yields frames; full sequences are tens of GB."""

    @property
    def name(self) -> str: ...

    @property
    def sensor(self) -> SensorKind: ...

    @property
    def calibration(self) -> PinholeCalibration: ...

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[SensorFrame]:
        """Every frame in order (``frame(0)``, ``frame(1)``, ...); a bad frame's error ends the iteration."""
        ...

    def frame(self, index: int) -> SensorFrame:
        """Frame ``index`` (0-based position in the source); FrameReadError when its files cannot be
        read or decoded (the next frames may still be good)."""
        ...

    def stamps_ns(self) -> np.ndarray:
        """All frame stamps (N,) int64, known without loading images."""
        ...

    def ground_truth(self) -> Trajectory | None:
        """Poses of the (rectified left) camera, or None when the dataset has none."""
        ...

    def imu(self) -> ImuSamples | None:
        """IMU samples, or None when the dataset has none."""
        ...


@contextmanager
def reading_frame(index: int) -> Iterator[None]:
    """Turn an ImageReadError raised while reading frame ``index`` into a FrameReadError naming the frame."""
    try:
        yield
    except FrameReadError:
        raise
    except ImageReadError as exc:
        raise FrameReadError(index, str(exc), exc.path, exc.reason) from exc


def check_frame_index(name: str, index: int, count: int) -> None:
    """Raise DatasetError unless ``index`` is a frame position of a source of ``count`` frames."""
    if not 0 <= index < count:
        raise DatasetError(f"{name} has no frame {index}: it has {count} frames, numbered 0 to {count - 1}")
