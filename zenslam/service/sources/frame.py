"""What every source yields: timestamped sensor frames, IMU samples, and the Source protocol."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.trajectory import Trajectory


@dataclass(frozen=True)
class SensorFrame:
    """One synchronised capture.

    ``left`` is the rectified, undistorted grey image (uint8, HxW) of the left / only camera.
    ``right`` is the rectified right image for stereo, ``depth_m`` the metric depth (float32, HxW,
    0 where unknown) registered to ``left`` for RGB-D.
    """

    index: int
    stamp_ns: int
    left: np.ndarray
    right: np.ndarray | None = None
    depth_m: np.ndarray | None = None


@dataclass(frozen=True)
class ImuSamples:
    """IMU measurements in the IMU (body) frame: gyro rad/s, accelerometer m/s^2, at ``stamps_ns``."""

    stamps_ns: np.ndarray  # (N,) int64
    gyro_rad_s: np.ndarray  # (N, 3)
    accel_m_s2: np.ndarray  # (N, 3)
    T_cam_imu: np.ndarray  # (4, 4) maps IMU coordinates to the (rectified left) camera frame


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
