"""The tracking states and poses a run's hub received, kept as columns of machine numbers.

The hub keeps every frame's state and pose until the run's outputs are written, so a long run's
hub grows with its frames. As Python objects (a state dataclass, two 4x4 arrays, two dict
entries) a frame costs a few times its numbers' bytes; as columns it costs little more than
them, with no per-frame object for the garbage collector to walk (benchmarks/soak.md).

A state arriving again for a frame it already has (a restarted stage repeats its newest one)
replaces it, as does a pose for a stamp already posed: the newest word wins.
"""

from __future__ import annotations

import logging
from array import array
from dataclasses import dataclass
from typing import get_args

import numpy as np

from zenslam.schemas import codec

logger = logging.getLogger(__name__)

_STATE_NAMES: tuple[str, ...] = get_args(codec.TrackingStateName)
_STATE_CODE = {name: code for code, name in enumerate(_STATE_NAMES)}
_HAS_POSE, _RELOCALISED = 1, 2  # bits of a row's flags
# A state whose frame index is this far past the newest is refused: no source skips a million
# frames, and the index -> row column would grow to its size (a damaged message on the bus).
MAX_INDEX_JUMP = 1_000_000


class FrameTable:
    """States by frame index (one row per frame) and poses by stamp, as columns."""

    def __init__(self) -> None:
        self._row_of_index = array("q")  # frame index -> its row, -1 for a frame without a state
        self._index = array("q")
        self._stamp = array("q")
        self._state = array("b")  # code into _STATE_NAMES
        self._reason = array("h")  # code into self._reasons
        self._n_tracked = array("q")
        self._flags = array("b")
        self._keyframe = array("q")
        self._reference = array("q")
        self._T_reference = array("d")  # 16 per row, row-major; NaN for a state without a reference
        self._reasons: list[str | None] = [None]
        self._reason_codes: dict[str | None, int] = {None: 0}
        self._pose_stamp = array("q")
        self._pose_T = array("d")  # 16 per pose, row-major
        self.newest_keyframe_id = -1  # the largest keyframe id a state named, -1 none

    def __len__(self) -> int:
        """Frames with a state."""
        return len(self._index)

    def has(self, index: int) -> bool:
        return 0 <= index < len(self._row_of_index) and self._row_of_index[index] >= 0

    def newest_index(self) -> int:
        """The largest frame index with a state, -1 none."""
        return len(self._row_of_index) - 1 if len(self._index) else -1

    def add_state(self, state: codec.TrackingStateMessage) -> bool:
        """Keep ``state`` (replacing an earlier one of its frame); False if it was refused."""
        i = int(state.index)
        if i < 0 or i > len(self._row_of_index) + MAX_INDEX_JUMP:
            logger.warning("tracking state of frame %d refused: frame indices run from 0, the newest is %d", i, self.newest_index())
            return False
        if i >= len(self._row_of_index):
            self._row_of_index.extend([-1] * (i + 1 - len(self._row_of_index)))
        T = np.full(16, np.nan) if state.T_reference_cam is None else np.asarray(state.T_reference_cam, dtype=float).reshape(16)
        reason = self._reason_codes.setdefault(state.lost_reason, len(self._reasons))
        if reason == len(self._reasons):
            self._reasons.append(state.lost_reason)
        flags = (_HAS_POSE if state.has_pose else 0) | (_RELOCALISED if state.relocalised else 0)
        row = self._row_of_index[i]
        columns = (
            (self._index, i), (self._stamp, int(state.stamp_ns)), (self._state, _STATE_CODE[state.state]),
            (self._reason, reason), (self._n_tracked, int(state.n_tracked)), (self._flags, flags),
            (self._keyframe, int(state.keyframe_id)), (self._reference, int(state.reference_keyframe_id)),
        )  # fmt: skip
        if row < 0:
            self._row_of_index[i] = len(self._index)
            for column, value in columns:
                column.append(value)
            self._T_reference.extend(T.tolist())
        else:
            for column, value in columns:
                column[row] = value
            self._T_reference[16 * row : 16 * row + 16] = array("d", T.tolist())
        self.newest_keyframe_id = max(self.newest_keyframe_id, int(state.keyframe_id))
        return True

    def add_pose(self, stamp_ns: int, T_world_cam: np.ndarray) -> None:
        self._pose_stamp.append(int(stamp_ns))
        self._pose_T.extend(np.asarray(T_world_cam, dtype=float).reshape(16).tolist())

    def states(self) -> FrameStates:
        """Every frame's state, in frame order."""
        n = len(self._index)
        order = np.argsort(np.frombuffer(self._index, dtype=np.int64), kind="stable") if n else np.zeros(0, np.int64)
        T_reference = np.frombuffer(self._T_reference, dtype=float).reshape(-1, 4, 4)[order] if n else np.zeros((0, 4, 4))

        def column(values: array, dtype) -> np.ndarray:
            return np.frombuffer(values, dtype=dtype)[order] if len(values) else np.zeros(0, dtype)

        return FrameStates(
            index=column(self._index, np.int64),
            stamp_ns=column(self._stamp, np.int64),
            state_code=column(self._state, np.int8),
            reason_code=column(self._reason, np.int16),
            n_tracked=column(self._n_tracked, np.int64),
            flags=column(self._flags, np.int8),
            keyframe_id=column(self._keyframe, np.int64),
            reference_keyframe_id=column(self._reference, np.int64),
            T_reference_cam=T_reference,
            reasons=tuple(self._reasons),
        )

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(stamps_ns (P,), T_world_cam (P, 4, 4)) of every posed stamp, the newest pose of each, by stamp."""
        if not len(self._pose_stamp):
            return np.zeros(0, np.int64), np.zeros((0, 4, 4))
        stamps = np.frombuffer(self._pose_stamp, dtype=np.int64)
        newest_first = stamps[::-1]
        unique, first = np.unique(newest_first, return_index=True)  # the newest of each stamp, by stamp
        rows = len(stamps) - 1 - first
        return unique, np.frombuffer(self._pose_T, dtype=float).reshape(-1, 4, 4)[rows]

    def missing_poses(self) -> int:
        """States that announced a pose (has_pose) whose pose has not arrived."""
        if not len(self._index):
            return 0
        posed = np.frombuffer(self._stamp, dtype=np.int64)[(np.frombuffer(self._flags, dtype=np.int8) & _HAS_POSE) != 0]
        if not len(self._pose_stamp):
            return len(posed)
        return int(np.count_nonzero(~np.isin(posed, np.frombuffer(self._pose_stamp, dtype=np.int64))))


@dataclass(frozen=True)
class FrameStates:
    """A snapshot of the states as arrays over frames in index order (``FrameTable.states``)."""

    index: np.ndarray  # (F,) int64
    stamp_ns: np.ndarray  # (F,) int64
    state_code: np.ndarray  # (F,) int8, into the names of codec.TrackingStateName
    reason_code: np.ndarray  # (F,) int16, into ``reasons``
    n_tracked: np.ndarray  # (F,) int64
    flags: np.ndarray  # (F,) int8: has_pose, relocalised bits
    keyframe_id: np.ndarray  # (F,) int64, -1 none
    reference_keyframe_id: np.ndarray  # (F,) int64, -1 none
    T_reference_cam: np.ndarray  # (F, 4, 4), NaN for a frame without a reference
    reasons: tuple[str | None, ...]  # lost reasons by code

    def __len__(self) -> int:
        return len(self.index)

    def is_state(self, name: str) -> np.ndarray:
        """(F,) bool: frames in state ``name`` (ok, lost, initializing)."""
        return self.state_code == _STATE_CODE[name]

    @property
    def has_pose(self) -> np.ndarray:
        return (self.flags & _HAS_POSE) != 0

    @property
    def relocalised(self) -> np.ndarray:
        return (self.flags & _RELOCALISED) != 0

    def lost_reasons(self, mask: np.ndarray) -> list[str | None]:
        """The lost reason of each frame in ``mask``, in order."""
        return [self.reasons[code] for code in self.reason_code[mask].tolist()]

    def message(self, k: int) -> codec.TrackingStateMessage:
        """Row ``k`` as the message it came in (without its timings: the hub keeps those apart)."""
        T = self.T_reference_cam[k]
        return codec.TrackingStateMessage(
            index=int(self.index[k]), stamp_ns=int(self.stamp_ns[k]), state=_STATE_NAMES[self.state_code[k]],  # type: ignore[arg-type]
            lost_reason=self.reasons[self.reason_code[k]], n_tracked=int(self.n_tracked[k]), has_pose=bool(self.has_pose[k]),
            keyframe_id=int(self.keyframe_id[k]), reference_keyframe_id=int(self.reference_keyframe_id[k]),
            T_reference_cam=None if np.isnan(T[0, 0]) else T.copy(), relocalised=bool(self.relocalised[k]),
        )  # fmt: skip
