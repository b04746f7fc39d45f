"""The map cache's points: a struct of arrays indexed by row (position, descriptor, viewing
direction, scale-invariance range, tracking statistics, validity, covariance) with the index
from point id to row."""

from __future__ import annotations

import numpy as np

from zenslam.frontend.id_index import IdIndex
from zenslam.frontend.map_arrays import POINT_ARRAYS, compacted, grow
from zenslam.schemas.map_update import MapUpdate


class PointTable:
    """Rows ``[0, n)`` of ``arrays`` (each array's capacity may be larger) are the points held;
    removed points keep their row with ``valid`` False until the table is compacted."""

    def __init__(self) -> None:
        self.arrays = {name: np.zeros((0, *shape), dtype=dtype) for name, (shape, dtype) in POINT_ARRAYS.items()}
        self.n = 0
        self._id_index = IdIndex()

    def view(self, name: str) -> np.ndarray:
        """The rows in use of the array ``name``."""
        return self.arrays[name][: self.n]

    def rows_of_ids(self, point_ids: np.ndarray) -> np.ndarray:
        """Rows (int64) of point ids; -1 for negative or unknown ids."""
        return self._id_index.rows(point_ids)

    def append(
        self, ids: np.ndarray, p_world: np.ndarray, descriptors: np.ndarray, normals: np.ndarray,
        min_distance_m: np.ndarray, max_distance_m: np.ndarray,
    ) -> np.ndarray:
        """New valid points, seen and found once, observed by no keyframe yet; returns their rows."""
        start, n_new = self.n, len(ids)
        grow(self.arrays, POINT_ARRAYS, start + n_new)
        rows = np.arange(start, start + n_new, dtype=np.int64)
        pts = self.arrays
        pts["ids"][rows] = ids
        pts["p_world"][rows] = p_world
        pts["descriptors"][rows] = descriptors
        pts["normals"][rows] = normals
        pts["min_distance_m"][rows] = min_distance_m
        pts["max_distance_m"][rows] = max_distance_m
        pts["n_visible"][rows] = 1
        pts["n_found"][rows] = 1
        pts["n_observations"][rows] = 0
        pts["valid"][rows] = True
        self.n = start + n_new
        self._id_index.add(ids, rows)
        return rows

    def replace(self, update: MapUpdate, observed_ids: np.ndarray) -> None:
        """Replace the points ``update`` lists that the table holds (position, descriptor, viewing
        direction, distance range; valid again) and create the unknown ones among ``observed_ids``."""
        rows = self.rows_of_ids(update.point_ids)
        unknown = np.flatnonzero(rows < 0)
        unknown = unknown[np.isin(update.point_ids[unknown], observed_ids)]
        pts = self.arrays
        if len(unknown):
            start = self.n
            grow(pts, POINT_ARRAYS, start + len(unknown))
            rows[unknown] = np.arange(start, start + len(unknown))
            self.n = start + len(unknown)
            new = rows[unknown]
            pts["ids"][new] = update.point_ids[unknown]
            pts["n_visible"][new] = 1
            pts["n_found"][new] = 1
            pts["n_observations"][new] = 0
            self._id_index.add(update.point_ids[unknown], new)
        listed = np.flatnonzero(rows >= 0)
        rows = rows[listed]
        pts["p_world"][rows] = update.p_world[listed]
        pts["descriptors"][rows] = update.descriptors[listed]
        pts["normals"][rows] = update.normals[listed]
        pts["min_distance_m"][rows] = update.min_distance_m[listed]
        pts["max_distance_m"][rows] = update.max_distance_m[listed]
        pts["valid"][rows] = True

    def keep(self, rows: np.ndarray) -> None:
        """Keep only ``rows`` (ascending), moved to the front in their order; the id index follows."""
        self.arrays = compacted(self.arrays, POINT_ARRAYS, rows)
        self.n = len(rows)
        self._id_index = IdIndex()
        self._id_index.add(self.arrays["ids"][: self.n], np.arange(self.n, dtype=np.int64))

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays (their capacity) and of the id index."""
        return int(sum(a.nbytes for a in self.arrays.values())) + self._id_index.nbytes
