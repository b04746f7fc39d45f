"""The zenslam exception hierarchy: one root, specific subclasses whose messages say what to do."""

from __future__ import annotations


class ZenslamError(Exception):
    """Root of every error zenslam raises on purpose."""


class DatasetError(ZenslamError):
    """A dataset on disk is missing, malformed or inconsistent."""


class CalibrationError(DatasetError):
    """Camera or sensor calibration is missing or invalid."""


class ImageReadError(DatasetError):
    """An image file is missing, unreadable or has the wrong size."""


class TimestampError(DatasetError):
    """Timestamps are not strictly increasing, or cannot be parsed."""


class ConfigError(ZenslamError):
    """A configuration file or value is invalid."""


class SourceSpecError(ZenslamError):
    """A source name such as ``kitti:<path>`` cannot be understood."""


class TrajectoryError(ZenslamError):
    """A trajectory file cannot be read, or two trajectories cannot be compared."""


class MessageError(ZenslamError):
    """A bus message cannot be encoded or decoded (wrong schema, truncated, inconsistent arrays)."""


class BusError(ZenslamError):
    """The bus cannot be opened, or a peer process did not appear or answer in time."""


class ProcessError(ZenslamError):
    """A stage process failed to start, died, or did not stop when asked."""


class RecordingError(ZenslamError):
    """A recording cannot be opened, read or written."""
