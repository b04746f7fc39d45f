"""The Source protocol: what every dataset reader and scene implements (frames are schemas.sensor_data)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.schemas.sensor_data import ImuSamples, SensorFrame
from zenslam.trajectory import Trajectory

__all__ = ["ImuSamples", "SensorFrame", "Source"]


class Source(Protocol):
    """A dataset or scene that lazily yields frames; full sequences are tens of GB."""

    @property
    def name(self) -> str: ...

    @property
    def sensor(self) -> SensorKind: ...

    @property
    def calibration(self) -> PinholeCalibration: ...

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[SensorFrame]: ...

    def stamps_ns(self) -> np.ndarray:
        """All frame stamps (N,) int64, known without loading images."""
        ...

    def ground_truth(self) -> Trajectory | None:
        """Poses of the (rectified left) camera, or None when the dataset has none."""
        ...

    def imu(self) -> ImuSamples | None:
        """IMU samples, or None when the dataset has none."""
        ...
