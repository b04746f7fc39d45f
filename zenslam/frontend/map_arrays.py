"""The map cache's storage: points and observations as structs of arrays indexed by row, grown
and compacted in place of per-point objects, and the one-observation-per-point rule of a keyframe."""

from __future__ import annotations

import numpy as np

# name: (shape of one row, dtype)
POINT_ARRAYS = {
    "ids": ((), np.int64),
    "p_world": ((3,), np.float64),
    "descriptors": ((32,), np.uint8),
    "normals": ((3,), np.float64),
    "min_distance_m": ((), np.float64),
    "max_distance_m": ((), np.float64),
    "n_visible": ((), np.int64),
    "n_found": ((), np.int64),
    "n_observations": ((), np.int64),
    "valid": ((), np.bool_),
    "covariance": ((3, 3), np.float64),
}
OBS_ARRAYS = {"row": ((), np.int64), "slot": ((), np.int64), "keypoint": ((), np.int64), "desc": ((32,), np.uint8)}


def grow(arrays: dict[str, np.ndarray], spec: dict, needed: int) -> None:
    """Make room for ``needed`` rows in ``arrays`` (of ``spec``), at least doubling their capacity."""
    capacity = next(iter(arrays.values())).shape[0]
    if needed <= capacity:
        return
    new_capacity = max(needed, 2 * capacity, 1024)
    for name, (shape, dtype) in spec.items():
        bigger = np.zeros((new_capacity, *shape), dtype=dtype)
        bigger[:capacity] = arrays[name]
        arrays[name] = bigger


def compacted(arrays: dict[str, np.ndarray], spec: dict, index: np.ndarray) -> dict[str, np.ndarray]:
    """The rows ``index`` of ``arrays``, moved to the front of new arrays with room to grow by half."""
    capacity = max(len(index) + len(index) // 2, 1024)
    out = {}
    for name, (shape, dtype) in spec.items():
        out[name] = np.zeros((capacity, *shape), dtype=dtype)
        out[name][: len(index)] = arrays[name][index]
    return out


def one_observation_per_point(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The keypoints (ascending) and point rows a keyframe observes, from each keypoint's point row
    ``rows`` (-1 none): a point associated with two keypoints is observed at the first."""
    keypoints = np.flatnonzero(rows >= 0)
    observed = rows[keypoints]
    if len(observed) > 1 and not np.all(np.diff(np.sort(observed))):  # not all distinct (rare): unique pass
        _, first = np.unique(observed, return_index=True)
        keypoints = keypoints[np.sort(first)]
        observed = rows[keypoints]
    return keypoints, observed
