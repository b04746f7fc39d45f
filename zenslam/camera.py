"""Rectified pinhole camera calibration shared by every stage (mono, stereo or RGB-D)."""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from zenslam.errors import CalibrationError

logger = logging.getLogger(__name__)

SensorKind = Literal["mono", "stereo", "rgbd"]

# Settings files often state the size of a sibling sequence's images (ORB-SLAM3's KITTI04-12.yaml says
# 1241x376, the images are 1226x370): intrinsics that close still describe the images, as ORB-SLAM
# takes them. A larger difference means a calibration of another camera or resolution.
_SIZE_SLACK = 0.1  # largest relative difference of width or height accepted, fraction


@dataclass(frozen=True)
class PinholeCalibration:
    """Intrinsics of the rectified left (or only) camera; images are distortion-free.

    fx, fy, cx, cy are in pixels; width/height in pixels. ``baseline_m`` is the stereo baseline
    in metres (for RGB-D, the virtual baseline used to make a right coordinate from depth, as
    ORB-SLAM does with ``bf``); ``None`` for a mono camera.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    baseline_m: float | None = None

    def __post_init__(self) -> None:
        problems = []
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                problems.append(f"{name}={value} must be a positive focal length in pixels")
        for name in ("cx", "cy"):
            if not math.isfinite(getattr(self, name)):
                problems.append(f"{name}={getattr(self, name)} must be finite")
        if self.width <= 0 or self.height <= 0:
            problems.append(f"image size {self.width}x{self.height} must be positive")
        if self.baseline_m is not None and not (math.isfinite(self.baseline_m) and self.baseline_m > 0):
            problems.append(f"baseline_m={self.baseline_m} must be a positive distance in metres")
        if problems:
            raise CalibrationError("invalid camera calibration: " + "; ".join(problems))

    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def bf(self) -> float:
        """Baseline times fx (pixels x metres): disparity = bf / depth."""
        if self.baseline_m is None:
            raise CalibrationError("a mono camera has no baseline; bf is defined for stereo and RGB-D only")
        return self.baseline_m * self.fx

    def fitted_to(self, width: int, height: int) -> PinholeCalibration:
        """This calibration for images of ``width`` x ``height`` pixels (the images a source delivers).

        A stated size within 10% of the images' in each dimension, with the principal point inside
        them, keeps the intrinsics and takes the images' size, with a warning naming both sizes;
        anything else raises CalibrationError.
        """
        if (self.width, self.height) == (width, height):
            return self
        stated, actual = f"{self.width}x{self.height}", f"{width}x{height}"
        if not (0.0 <= self.cx < width and 0.0 <= self.cy < height):
            problem = f"its principal point ({self.cx:g}, {self.cy:g}) lies outside the {actual} images"
        elif abs(self.width - width) > _SIZE_SLACK * width or abs(self.height - height) > _SIZE_SLACK * height:
            problem = f"the sizes differ by more than {_SIZE_SLACK:.0%}"
        else:
            logger.warning(
                "the calibration states images of %s but the source's are %s; using its intrinsics "
                "(principal point (%g, %g)) with the images' size", stated, actual, self.cx, self.cy,
            )
            return dataclasses.replace(self, width=width, height=height)
        raise CalibrationError(
            f"the calibration is for {stated} images but the source's are {actual}: {problem}; "
            "give the calibration of these images (e.g. the settings file of this sequence)"
        )

    def summary(self) -> str:
        """One line for people: intrinsics, size and baseline."""
        base = f"fx={self.fx:.3f} fy={self.fy:.3f} cx={self.cx:.3f} cy={self.cy:.3f} size={self.width}x{self.height}"
        if self.baseline_m is not None:
            base += f" baseline={self.baseline_m:.4f} m"
        return base
