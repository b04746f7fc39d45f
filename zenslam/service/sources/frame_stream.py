"""The frames a source process sends: each frame of a source read in turn, bad ones reported as SkippedFrame.

A frame is skipped when it cannot be read or decoded (FrameReadError: reasons ``corrupt``,
``missing``, ``unreadable``), when its stamp does not come after the last frame passed on
(``stamp_backwards``, ``stamp_repeat``: the frontend's motion model and every consumer of the
poses need time to move forward), or when ``source.faults`` drops it (``drop``). Frames keep
their source index, so a skipped frame leaves a gap in the indices that reach the frontend.
Errors that concern the whole source (a file of the dataset gone, a bug) are not skips: they end
the stream.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

from zenslam.errors import FrameReadError, TimestampError, ZenslamError
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.service.sources.faults import FaultInjector
from zenslam.service.sources.frame import Source

SkipReason = Literal["corrupt", "missing", "unreadable", "stamp_backwards", "stamp_repeat", "drop"]
_READ_REASONS: dict[str, SkipReason] = {"corrupt": "corrupt", "missing": "missing", "unreadable": "unreadable"}


@dataclass(frozen=True)
class SkippedFrame:
    """A frame of the source that is not sent, why, and the error that says so (names the frame and file)."""

    index: int  # position in the source
    reason: SkipReason
    error: ZenslamError


def stamp_problem(index: int, stamp_ns: int, previous_index: int, previous_ns: int) -> SkippedFrame | None:
    """A SkippedFrame when frame ``index``'s stamp does not come after ``previous_ns`` (the frame passed on last)."""
    if stamp_ns > previous_ns:
        return None
    reason: SkipReason = "stamp_repeat" if stamp_ns == previous_ns else "stamp_backwards"
    what = "repeats" if stamp_ns == previous_ns else f"is {(previous_ns - stamp_ns) * 1e-6:.3f} ms before"
    error = TimestampError(
        f"frame {index}: stamp {stamp_ns} ns {what} the stamp of frame {previous_index} ({previous_ns} ns); "
        "stamps must strictly increase"
    )
    return SkippedFrame(index, reason, error)


def frame_stream(source: Source, injector: FaultInjector | None = None, start: int = 0) -> Iterator[SensorFrame | SkippedFrame]:
    """Every frame of ``source`` from index ``start`` on, in order, with ``injector``'s faults
    applied: the frame, or why it was skipped."""
    injector = injector or FaultInjector()
    previous: tuple[int, int] | None = None  # (index, stamp_ns) of the last frame passed on
    for index in range(max(start, 0), len(source)):
        try:
            frame = injector.read(source, index)
        except FrameReadError as exc:
            yield SkippedFrame(index, _READ_REASONS.get(exc.reason, "corrupt"), exc)
            continue
        if frame is None:
            fault = injector.fault_at(index)
            detail = fault.describe() if fault is not None else ""
            yield SkippedFrame(index, "drop", ZenslamError(f"frame {index}: dropped by source.faults {detail}"))
            continue
        problem = None if previous is None else stamp_problem(index, frame.stamp_ns, *previous)
        if problem is not None:
            yield problem
            continue
        previous = (index, frame.stamp_ns)
        yield frame
