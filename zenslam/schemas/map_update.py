"""The backend's changes to the map: what the frontend applies to its local copy.

An update has a kind: ``keyframe`` answers one keyframe (its local mapping; in lockstep the
frontend waits for it), ``correction`` is a change no keyframe asked for (a loop closure, a
global bundle adjustment) and is applied whenever it arrives.

Semantics are replacement, not deltas, so applying an update twice is harmless: every keyframe
listed gets its pose and its whole keypoint-to-point association array replaced; every point
listed gets its position, representative descriptor, mean viewing direction and scale-invariance
distances replaced (created if the frontend has not seen it); removed ids are deleted.
Point ids created by the backend live in their own id space (``BACKEND_POINT_ID_BASE`` and up),
disjoint from the frontend's (0 and up), so neither process needs a round trip to name a point.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

MapUpdateKind = Literal["keyframe", "correction"]

# Point ids at or above this value are created by the backend; below it by the frontend.
BACKEND_POINT_ID_BASE = 1 << 62


def _empty(shape: tuple[int, ...], dtype: type) -> np.ndarray:
    return np.zeros(shape, dtype=dtype)


@dataclass(frozen=True)
class KeyframeCorrection:
    """A keyframe's optimised pose and its complete association of keypoints to map points."""

    id: int
    T_world_cam: np.ndarray  # (4, 4) maps camera coordinates to world
    map_point_ids: np.ndarray  # (N,) int64 per keypoint, -1 if none


@dataclass(frozen=True)
class MapUpdate:
    """Everything the backend changed while processing keyframe ``keyframe_id`` (kind ``keyframe``),
    or in a correction that covers the keyframes up to ``keyframe_id`` (kind ``correction``)."""

    keyframe_id: int  # the keyframe whose processing produced this update (the newest one a correction covers)
    stamp_ns: int  # that keyframe's stamp
    keyframes: tuple[KeyframeCorrection, ...] = ()
    point_ids: np.ndarray = field(default_factory=lambda: _empty((0,), np.int64))  # (P,)
    p_world: np.ndarray = field(default_factory=lambda: _empty((0, 3), np.float64))  # (P, 3) metres
    descriptors: np.ndarray = field(default_factory=lambda: _empty((0, 32), np.uint8))  # (P, 32)
    normals: np.ndarray = field(default_factory=lambda: _empty((0, 3), np.float64))  # (P, 3) unit, world frame
    min_distance_m: np.ndarray = field(default_factory=lambda: _empty((0,), np.float64))  # (P,)
    max_distance_m: np.ndarray = field(default_factory=lambda: _empty((0,), np.float64))  # (P,)
    removed_point_ids: np.ndarray = field(default_factory=lambda: _empty((0,), np.int64))  # (R,)
    removed_keyframe_ids: np.ndarray = field(default_factory=lambda: _empty((0,), np.int64))  # (Q,)
    kind: MapUpdateKind = "keyframe"
    # Updates the backend publishes right after this one (each may announce more after it): an
    # answer's local-mapping correction when it was published before its local BA, a loop's
    # correction found at this keyframe. Lockstep applies them before its next frame, or, with
    # ``corrections_after_next_frame``, before the frame after it, so where a correction lands in
    # the stream does not depend on timing.
    corrections_following: int = 0
    # An answer published before its keyframe's local BA (``backend.answer_before_local_ba``):
    # lockstep tracks one frame on it while the backend runs the BA.
    corrections_after_next_frame: bool = False

    @property
    def answers_keyframe(self) -> bool:
        """True when this is the answer to keyframe ``keyframe_id`` (what lockstep waits for)."""
        return self.kind == "keyframe"

    def __post_init__(self) -> None:
        n = len(self.point_ids)
        shapes = {
            "p_world": (self.p_world.shape, (n, 3)),
            "descriptors": (self.descriptors.shape, (n, 32)),
            "normals": (self.normals.shape, (n, 3)),
            "min_distance_m": (self.min_distance_m.shape, (n,)),
            "max_distance_m": (self.max_distance_m.shape, (n,)),
        }
        wrong = {k: v[0] for k, v in shapes.items() if v[0] != v[1]}
        if wrong:
            raise ValueError(f"MapUpdate for {n} points has mis-shaped arrays: {wrong}")
