"""Sensor data as every stage sees it: timestamped frames and IMU samples (decoded bus messages).

Sources produce these, ``codec`` carries them over the bus, and the stages consume them; they live
in ``schemas`` so that every process can use them without importing the service package.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
