"""Running a source as another sensor than its own: a stereo or RGB-D dataset played monocular.

ORB-SLAM3's monocular examples run on KITTI's and EuRoC's left images; ``zenslam run SOURCE
--sensor mono`` (``source.sensor``) does the same. A source can give less than it has (its left
image alone, with a calibration without baseline), never more: RGB-D from a stereo pair, or stereo
from an RGB-D camera, is refused with the sensors the source can give. Synthetic scenes render any
sensor, so they take the choice in their own configuration instead (``open_source``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import SourceSpecError
from zenslam.schemas.sensor_data import ImuSamples, SensorFrame
from zenslam.service.sources.frame import Source
from zenslam.trajectory import Trajectory

SENSOR_KINDS: tuple[SensorKind, ...] = ("mono", "stereo", "rgbd")


def sensors_of(own: SensorKind) -> tuple[SensorKind, ...]:
    """The sensors a source whose own sensor is ``own`` can be played as."""
    return (own,) if own == "mono" else (own, "mono")


def check_sensor_name(sensor: str, where: str) -> SensorKind:
    """``sensor`` if it names a sensor kind; SourceSpecError naming ``where`` it came from otherwise."""
    if sensor not in SENSOR_KINDS:
        raise SourceSpecError(f"{where}: unknown sensor {sensor!r}; choose one of {list(SENSOR_KINDS)}")
    return sensor  # type: ignore[return-value]


def as_sensor(source: Source, sensor: SensorKind) -> Source:
    """``source`` played as ``sensor``: itself when that is its own sensor, its left images alone for
    ``mono``; SourceSpecError when the source cannot give ``sensor``."""
    if sensor == source.sensor:
        return source
    if sensor not in sensors_of(source.sensor):
        raise SourceSpecError(
            f"{source.name} is a {source.sensor} source and cannot be played as {sensor}: choose --sensor "
            f"{' or '.join(sensors_of(source.sensor))} (a source gives its own sensor, or its left images alone as mono)"
        )
    return MonocularView(source)


def mono_calibration(calibration: PinholeCalibration) -> PinholeCalibration:
    """``calibration`` without a baseline: the left camera alone."""
    return dataclasses.replace(calibration, baseline_m=None)


class MonocularView:
    """A stereo or RGB-D source's left images alone, with its ground truth, stamps and IMU."""

    def __init__(self, source: Source) -> None:
        self._source = source

    @property
    def name(self) -> str:
        return f"{self._source.name} (left images, monocular)"

    @property
    def sensor(self) -> SensorKind:
        return "mono"

    @property
    def calibration(self) -> PinholeCalibration:
        return mono_calibration(self._source.calibration)

    def __len__(self) -> int:
        return len(self._source)

    def __iter__(self) -> Iterator[SensorFrame]:
        return (self._left_only(frame) for frame in self._source)

    def frame(self, index: int) -> SensorFrame:
        return self._left_only(self._source.frame(index))

    def stamps_ns(self) -> np.ndarray:
        return self._source.stamps_ns()

    def ground_truth(self) -> Trajectory | None:
        return self._source.ground_truth()

    def imu(self) -> ImuSamples | None:
        return self._source.imu()

    @staticmethod
    def _left_only(frame: SensorFrame) -> SensorFrame:
        return dataclasses.replace(frame, right=None, depth_m=None)
