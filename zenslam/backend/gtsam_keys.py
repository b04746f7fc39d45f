"""The one place GTSAM keys are made: X pose, L landmark, V velocity, B IMU bias, from zenslam ids.

A GTSAM ``Symbol`` packs a character into the top 8 bits of a 64-bit key and an index into the
low 56 bits, so an id can be used as an index only if it is below 2**56. Keyframe ids count up
from 0 and always fit. Point ids come from two disjoint spaces (``zenslam.schemas.map_update``):
the frontend's, counting up from 0, and the backend's, counting up from
``BACKEND_POINT_ID_BASE = 2**62``, which do not fit. Rather than renumbering points densely per
problem (keys would then change from one local BA to the next, which breaks any persistent graph
and makes logs unreadable), the landmark id space is split deterministically inside the 56 bits:

    frontend point id i, 0 <= i < 2**55            ->  L(i)
    backend point id  BASE + j, 0 <= j < 2**55     ->  L(2**55 + j)

so the mapping is a bijection, stable across problems and processes, and ``l<i>`` in a GTSAM
printout is point ``i`` for every frontend point. Neither process can plausibly create 2**55
(3.6e16) points; an id outside both ranges is a bug upstream and raises ``ZenslamError``.
"""

from __future__ import annotations

import numpy as np
from gtsam import symbol_shorthand

from zenslam.errors import ZenslamError
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE

# Bits of a GTSAM Symbol's index (the character takes the top 8 of 64).
_INDEX_BITS = 56
_INDEX_MASK = (1 << _INDEX_BITS) - 1
# Half of the index space per point id space: frontend ids below, backend ids (offset) above.
_HALF = 1 << (_INDEX_BITS - 1)


def pose_key(keyframe_id: int) -> int:
    """The key X(keyframe_id) of a keyframe's pose variable (gtsam.Pose3, T_world_cam)."""
    return symbol_shorthand.X(_checked_index(keyframe_id, "keyframe"))


def velocity_key(keyframe_id: int) -> int:
    """The key V(keyframe_id) of a keyframe's velocity variable (world frame, m/s)."""
    return symbol_shorthand.V(_checked_index(keyframe_id, "keyframe"))


def bias_key(keyframe_id: int) -> int:
    """The key B(keyframe_id) of a keyframe's IMU bias variable."""
    return symbol_shorthand.B(_checked_index(keyframe_id, "keyframe"))


def landmark_index(point_id: int) -> int:
    """The 56-bit Symbol index of a point id (the split described in the module docstring)."""
    point_id = int(point_id)
    if 0 <= point_id < _HALF:
        return point_id
    if BACKEND_POINT_ID_BASE <= point_id < BACKEND_POINT_ID_BASE + _HALF:
        return _HALF + (point_id - BACKEND_POINT_ID_BASE)
    raise ZenslamError(
        f"point id {point_id} has no GTSAM key: point ids must lie in [0, 2**55) (frontend) or "
        f"[{BACKEND_POINT_ID_BASE}, {BACKEND_POINT_ID_BASE} + 2**55) (backend); the id was made outside "
        "both id spaces, check the process that created it"
    )


def landmark_key(point_id: int) -> int:
    """The key L(...) of a map point's position variable (gtsam.Point3, p_world in metres)."""
    return symbol_shorthand.L(landmark_index(point_id))


def landmark_keys(point_ids: np.ndarray) -> list[int]:
    """The landmark keys of an array of point ids, in order (see ``landmark_key``)."""
    return [landmark_key(i) for i in np.asarray(point_ids, dtype=np.int64).tolist()]


def pose_keys(keyframe_ids: np.ndarray) -> list[int]:
    """The pose keys of an array of keyframe ids, in order (see ``pose_key``)."""
    return [pose_key(i) for i in np.asarray(keyframe_ids, dtype=np.int64).tolist()]


def point_id_of_key(key: int) -> int:
    """The point id whose landmark key is ``key``; inverse of ``landmark_key``."""
    char, index = _split(key)
    if char != "l":
        raise ZenslamError(f"GTSAM key {key} ({char}{index}) is not a landmark key L(...)")
    return index if index < _HALF else BACKEND_POINT_ID_BASE + (index - _HALF)


def keyframe_id_of_key(key: int) -> int:
    """The keyframe id of a pose, velocity or bias key X/V/B(keyframe_id)."""
    char, index = _split(key)
    if char not in ("x", "v", "b"):
        raise ZenslamError(f"GTSAM key {key} ({char}{index}) is not a keyframe key X/V/B(...)")
    return index


def key_kind(key: int) -> str:
    """The Symbol character of a key: 'x' pose, 'l' landmark, 'v' velocity, 'b' bias (others as found)."""
    return _split(key)[0]


def _split(key: int) -> tuple[str, int]:
    key = int(key)
    return chr((key >> _INDEX_BITS) & 0xFF), key & _INDEX_MASK


def _checked_index(keyframe_id: int, what: str) -> int:
    keyframe_id = int(keyframe_id)
    if not 0 <= keyframe_id <= _INDEX_MASK:
        raise ZenslamError(
            f"{what} id {keyframe_id} has no GTSAM key: ids must lie in [0, 2**56); "
            "keyframe ids count up from 0, check the process that created it"
        )
    return keyframe_id
