"""The zenslam exception hierarchy: one root, specific subclasses whose messages say what to do."""

from __future__ import annotations


class ZenslamError(Exception):
    """Root of every error zenslam raises on purpose."""


class DatasetError(ZenslamError):
    """A dataset on disk is missing, malformed or inconsistent."""


class CalibrationError(DatasetError):
    """Camera or sensor calibration is missing or invalid."""


class ImageReadError(DatasetError):
    """An image file is missing, unreadable or has the wrong size.

    ``path`` is the file (None when the image did not come from one) and ``reason`` one of
    ``missing``, ``unreadable`` (the file system refused it) or ``corrupt`` (it cannot be decoded,
    or is of the wrong size or type).
    """

    def __init__(self, message: str, path: str | None = None, reason: str = "corrupt"):
        super().__init__(message)
        self.path = path
        self.reason = reason


class FrameReadError(ImageReadError):
    """One frame of a source cannot be read or decoded: that frame is bad, not the dataset.

    Readers raise it from ``Source.frame(index)``; the source process skips the frame (or, with
    ``source.strict``, stops the run). A dataset that cannot be opened at all raises its other
    DatasetError subclasses when the source is opened, before any frame is sent.
    """

    def __init__(self, frame_index: int, message: str, path: str | None = None, reason: str = "corrupt"):
        super().__init__(f"frame {frame_index}: {message}", path, reason)
        self.frame_index = frame_index


class TimestampError(DatasetError):
    """Timestamps are not strictly increasing, or cannot be parsed."""


class ConfigError(ZenslamError):
    """A configuration file or value is invalid."""


class VocabularyError(ZenslamError):
    """A bag-of-words vocabulary file is missing, corrupt, or not one of 256-bit ORB descriptors."""


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
