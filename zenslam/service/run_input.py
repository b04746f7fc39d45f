"""What ``zenslam run`` knows of its input before the first frame: a dataset, or frames from the bus.

A dataset or scene is opened here to learn its name, sensor, frame count and ground truth. A bus
source (``zenoh:<key>``) is live: only the source process subscribes to it, its frame count is
unknown (the progress bar counts up), its sensor is the one ``--sensor`` asks for or the one the
recording's first frame says, and its ground truth comes from ``--ground-truth`` (a trajectory
file, or the spec of the dataset being published, whose ground truth is taken).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from zenslam.camera import SensorKind
from zenslam.errors import ConfigError, TrajectoryError, ZenslamError
from zenslam.schemas import codec
from zenslam.service import mcap_io
from zenslam.service.sources import SOURCE_KINDS, Source, is_bus_spec, open_source
from zenslam.service.sources.mcap_source import sensor_frame_topic
from zenslam.trajectory import Trajectory

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunInput:
    """The input of a run as far as it is known at its start."""

    name: str
    sensor: SensorKind | None  # None: a bus source's own, known from its first frame
    total: int | None  # frames to track (None: a bus source, until its publisher stops)
    ground_truth: Trajectory | None
    source: Source | None = None  # the opened dataset or scene (None for a bus source)
    image_size: tuple[int, int] | None = None  # (width, height) pixels, for fitting a calibration override

    @property
    def live(self) -> bool:
        """True for frames from the bus."""
        return self.source is None


def run_input(spec: str, sensor: SensorKind | None, max_frames: int | None, ground_truth: str | None) -> RunInput:
    """The input named by ``spec`` played as ``sensor``; ``ground_truth`` (``--ground-truth``) replaces the source's."""
    truth = None if ground_truth is None else read_ground_truth(ground_truth)
    if is_bus_spec(spec):
        return RunInput(f"{spec} (frames from the bus)", sensor, max_frames, truth)
    source = open_source(spec, sensor)
    total = len(source) if max_frames is None else min(len(source), max_frames)
    size = (source.calibration.width, source.calibration.height)
    return RunInput(source.name, source.sensor, total, truth or source.ground_truth(), source, size)


def read_ground_truth(value: str) -> Trajectory:
    """The ground truth named by ``value``: a source spec (``kitti:<root>/sequences/06``: that source's
    ground truth) or a trajectory file (TUM, EuRoC, or KITTI poses with stamps = frame index)."""
    kind = value.partition(":")[0]
    if kind in SOURCE_KINDS:
        # KITTI's poses are the left camera's: read as mono, a sequence of image_0 alone gives them too.
        truth = open_source(value, "mono" if kind == "kitti" else None).ground_truth()
        if truth is None:
            raise ConfigError(f"--ground-truth {value}: that source has no ground truth")
        return truth
    from zenslam.service.evaluation.trajectory_io import detect_format, read_trajectory

    path = Path(value).expanduser()
    if not path.is_file():
        raise ConfigError(
            f"--ground-truth {value}: no such file; give a trajectory file (TUM, EuRoC, KITTI) or a source spec such as "
            "kitti:<root>/sequences/NN"
        )
    try:
        return read_trajectory(path, detect_format(path, None))
    except TrajectoryError as exc:
        raise ConfigError(f"--ground-truth {value}: {exc}") from exc


def recorded_sensor(recording: Path) -> SensorKind | None:
    """The sensor of the first frame recorded in ``recording`` (a run's run.mcap), or None when it holds none."""
    if not recording.is_file():
        return None
    try:
        for message in mcap_io.iter_messages(recording, [sensor_frame_topic()], log_time_order=False):
            decoded = codec.decode_sensor_frame(message.data)
            if isinstance(decoded, codec.FrameMessage):
                return decoded.sensor
    except ZenslamError as exc:
        logger.warning("cannot read the sensor of the frames recorded in %s: %s", recording, exc)
    return None
