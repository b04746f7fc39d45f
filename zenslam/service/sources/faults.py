"""Fault injection for any source (``source.faults``): frames made black, dropped, corrupt, or stamped out of order.

Each fault covers the frames ``first_frame`` to ``last_frame`` (inclusive; positions in the source,
which are the frame indices of the dataset readers and synthetic scenes):

- ``black``: the camera images (left, and right for stereo) are replaced by black images of the same
  size and sent; RGB-D depth is kept (the depth sensor is another camera). Tracking then loses the
  camera, as behind a lens cap.
- ``drop``: the frame is never read nor sent, like a camera frame lost on its way.
- ``corrupt``: reading the frame fails as a corrupt image file would (FrameReadError, reason corrupt).
- ``stamp_backwards``: the frame's stamp goes back, before the previous frame's, by the frame's own
  interval after the previous one (so a range of them keeps going back).
- ``stamp_repeat``: the frame's stamp repeats the previous frame's.

"Previous" is the frame read just before, with its fault applied, whether or not it was sent.
The source process then handles these frames as it handles real ones (see ``frame_stream``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np

from zenslam.errors import ConfigError, FrameReadError
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.service.sources.frame import Source

FaultKind = Literal["black", "drop", "corrupt", "stamp_backwards", "stamp_repeat"]
FAULT_KINDS: tuple[str, ...] = get_args(FaultKind)
_STAMP_KINDS = ("stamp_backwards", "stamp_repeat")


@dataclass(frozen=True)
class FrameFault:
    """One injected fault over a range of frames (one entry of ``source.faults``)."""

    kind: FaultKind  # black | drop | corrupt | stamp_backwards | stamp_repeat (see the module docstring)
    first_frame: int  # frame index (position in the source) of the first frame affected, inclusive
    last_frame: int  # frame index of the last frame affected, inclusive

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ConfigError(f"fault {self.describe()}: kind {self.kind!r} is not one of {list(FAULT_KINDS)}")
        for name in ("first_frame", "last_frame"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ConfigError(f"fault {self.describe()}: {name}={value!r} must be a frame index >= 0")
        if self.last_frame < self.first_frame:
            raise ConfigError(
                f"fault {self.describe()}: last_frame {self.last_frame} is before first_frame {self.first_frame}; "
                "the range is inclusive, so one frame is first_frame = last_frame"
            )
        if self.kind in _STAMP_KINDS and self.first_frame == 0:
            raise ConfigError(
                f"fault {self.describe()}: a {self.kind} fault needs a previous frame's stamp; first_frame must be >= 1"
            )

    def covers(self, index: int) -> bool:
        return self.first_frame <= index <= self.last_frame

    def describe(self) -> str:
        """``{kind: drop, first_frame: 3, last_frame: 5}``, as the entry is written in YAML."""
        return f"{{kind: {self.kind}, first_frame: {self.first_frame}, last_frame: {self.last_frame}}}"


def check_faults(faults: tuple[FrameFault, ...], where: str = "source.faults") -> None:
    """Raise ConfigError naming two entries of ``faults`` that cover the same frame (one fault per frame)."""
    ordered = sorted(range(len(faults)), key=lambda k: faults[k].first_frame)
    for a, b in zip(ordered, ordered[1:]):
        if faults[b].first_frame <= faults[a].last_frame:
            raise ConfigError(
                f"{where}[{a}] {faults[a].describe()} and {where}[{b}] {faults[b].describe()} both cover frame "
                f"{faults[b].first_frame}; give each frame at most one fault"
            )


class FaultInjector:
    """Reads frames from a source with the faults applied; keeps the previous frame's stamp for stamp faults."""

    def __init__(self, faults: tuple[FrameFault, ...] = ()):
        check_faults(faults)
        self._faults = faults
        self._previous: tuple[int, int] | None = None  # (stamp as read, stamp given) of the previous frame read

    def fault_at(self, index: int) -> FrameFault | None:
        """The fault covering frame ``index``, or None."""
        return next((f for f in self._faults if f.covers(index)), None)

    def beyond(self, count: int) -> list[FrameFault]:
        """The faults that start past the last frame of a source of ``count`` frames (never applied)."""
        return [f for f in self._faults if f.first_frame >= count]

    def read(self, source: Source, index: int) -> SensorFrame | None:
        """Frame ``index`` of ``source`` with its fault applied; None when the fault drops it.

        Raises FrameReadError when the frame is made corrupt, or when the source cannot read it.
        """
        fault = self.fault_at(index)
        if fault is not None and fault.kind == "drop":
            return None
        if fault is not None and fault.kind == "corrupt":
            raise FrameReadError(index, f"made corrupt by source.faults {fault.describe()}", None, "corrupt")
        frame = source.frame(index)
        read_stamp_ns = frame.stamp_ns
        if fault is not None and fault.kind == "black":
            frame = black_frame(frame)
        elif fault is not None and fault.kind in _STAMP_KINDS and self._previous is not None:
            frame = dataclasses.replace(frame, stamp_ns=self._faulty_stamp(fault.kind, read_stamp_ns))
        self._previous = (read_stamp_ns, frame.stamp_ns)
        return frame

    def _faulty_stamp(self, kind: str, read_stamp_ns: int) -> int:
        assert self._previous is not None
        previous_read_ns, previous_given_ns = self._previous
        if kind == "stamp_repeat":
            return previous_given_ns
        return previous_given_ns - max(1, read_stamp_ns - previous_read_ns)


def black_frame(frame: SensorFrame) -> SensorFrame:
    """``frame`` with black camera images of the same size and type (depth, if any, kept)."""
    right = None if frame.right is None else np.zeros_like(frame.right)
    return dataclasses.replace(frame, left=np.zeros_like(frame.left), right=right)
