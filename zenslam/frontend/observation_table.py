"""The map cache's observations: one row per (point row, keyframe slot, keypoint) with the
keypoint's descriptor, as a struct of arrays in the order they were made, and what is read from
them: covisibility links, and each point's viewing direction and representative descriptor."""

from __future__ import annotations

import numpy as np

from zenslam.frontend.map_arrays import OBS_ARRAYS, compacted, grow
from zenslam.frontend.point_table import PointTable
from zenslam.map_point_rules import representative_offsets


class ObservationTable:
    """Rows ``[0, n)`` of ``arrays`` (``row``, ``slot``, ``keypoint``, ``desc``) are the observations held."""

    def __init__(self) -> None:
        self.arrays = {name: np.zeros((0, *shape), dtype=dtype) for name, (shape, dtype) in OBS_ARRAYS.items()}
        self.n = 0

    def view(self, name: str) -> np.ndarray:
        """The rows in use of the array ``name``."""
        return self.arrays[name][: self.n]

    def append(self, slot: int, rows: np.ndarray, keypoints: np.ndarray, desc: np.ndarray) -> None:
        """The keyframe in ``slot`` observes the points ``rows`` at ``keypoints`` with descriptors ``desc``."""
        start, n = self.n, len(rows)
        grow(self.arrays, OBS_ARRAYS, start + n)
        self.arrays["row"][start : start + n] = rows
        self.arrays["slot"][start : start + n] = slot
        self.arrays["keypoint"][start : start + n] = keypoints
        self.arrays["desc"][start : start + n] = desc
        self.n = start + n

    def drop(self, doomed_slots: np.ndarray) -> np.ndarray:
        """Delete every observation of the slots where ``doomed_slots`` (a mask over slots) is set,
        compacting the arrays once; returns the point rows those observations were of."""
        mine = doomed_slots[self.view("slot")]
        dropped = self.view("row")[mine]
        keep = np.flatnonzero(~mine)
        for name in OBS_ARRAYS:
            self.arrays[name][: len(keep)] = self.arrays[name][keep]
        self.n = len(keep)
        return dropped

    def keep(self, kept: np.ndarray, row_map: np.ndarray, slot_map: np.ndarray) -> None:
        """Keep the observations where ``kept`` (a mask over them) is set, in their order, with their
        rows and slots renumbered by ``row_map`` and ``slot_map``."""
        self.arrays = compacted(self.arrays, OBS_ARRAYS, np.flatnonzero(kept))
        self.n = int(np.count_nonzero(kept))
        self.arrays["row"][: self.n] = row_map[self.arrays["row"][: self.n]]
        self.arrays["slot"][: self.n] = slot_map[self.arrays["slot"][: self.n]]

    def links(self, slot: int, rows: np.ndarray, n_points: int, n_slots: int) -> dict[int, int]:
        """Covisibility links (other slot -> shared points) of ``slot`` observing the points ``rows``
        (of ``n_points`` rows), among ``n_slots`` keyframe slots."""
        in_kf = np.zeros(n_points, dtype=bool)
        in_kf[rows] = True
        weights = np.bincount(self.view("slot")[in_kf[self.view("row")]], minlength=n_slots)
        weights[slot] = 0
        return {int(s): int(weights[s]) for s in np.flatnonzero(weights)}

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays (their capacity)."""
        return int(sum(a.nbytes for a in self.arrays.values()))


def refresh_points(points: PointTable, observations: ObservationTable, kf_centres: np.ndarray, rows: np.ndarray) -> None:
    """Recompute the viewing directions and representative descriptors of the point ``rows`` from
    all their observations (``kf_centres``: (slots, 3) keyframe centres, world frame)."""
    if len(rows) == 0:
        return
    pts, n_points = points.arrays, points.n
    mask = np.zeros(n_points, dtype=bool)
    mask[rows] = True
    obs_rows = observations.view("row")
    entries = np.flatnonzero(mask[obs_rows])
    entries = entries[np.argsort(obs_rows[entries], kind="stable")]
    e_rows = obs_rows[entries]
    rays = pts["p_world"][e_rows] - kf_centres[observations.view("slot")[entries]]
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    counts = np.bincount(e_rows, minlength=n_points)
    sums = np.stack([np.bincount(e_rows, weights=rays[:, k], minlength=n_points) for k in range(3)], 1)
    pts["normals"][rows] = sums[rows] / counts[rows, None]
    starts = np.cumsum(counts) - counts  # first sorted entry of each row (rows outside have none)
    desc = observations.view("desc")[entries]
    observed = rows[counts[rows] > 0]
    chosen = starts[observed] + representative_offsets(desc, starts[observed], counts[observed])
    pts["descriptors"][observed] = desc[chosen]
