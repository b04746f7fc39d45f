"""The map points' per-point arrays (position, representative descriptor, viewing direction, distance range) as columns.

Each point gets the next row when it is created. Rows are never handed out twice, so a point
removed from the map keeps reading its own last values; the map moves its live points into a
fresh, compact store (``compacted``) once removed ones fill half of it. The per-keyframe work
reads and writes these columns for thousands of points at once (``BackendMap.point_geometry``,
the point refresh, fusion), where going through one object per point would cost a Python call
per point.
"""

from __future__ import annotations

import numpy as np

# Column name -> (row shape, dtype, value of a new row).
COLUMNS: dict[str, tuple[tuple[int, ...], type, float]] = {
    "p_world": ((3,), np.float64, 0.0),  # metres, world frame
    "descriptor": ((32,), np.uint8, 0),  # representative ORB descriptor
    "normal": ((3,), np.float64, 0.0),  # mean viewing direction, world frame (not renormalised)
    "min_distance_m": ((), np.float64, 0.0),  # scale-invariance range, metres
    "max_distance_m": ((), np.float64, np.inf),
}


class PointStore:
    """Columns of point rows, appended one row at a time."""

    def __init__(self, capacity: int = 1024) -> None:
        capacity = max(int(capacity), 1)
        self.p_world = np.zeros((capacity, 3))
        self.descriptor = np.zeros((capacity, 32), dtype=np.uint8)
        self.normal = np.zeros((capacity, 3))
        self.min_distance_m = np.zeros(capacity)
        self.max_distance_m = np.full(capacity, np.inf)
        self.n_rows = 0  # rows handed out

    @property
    def capacity(self) -> int:
        """Rows allocated in the columns."""
        return len(self.p_world)

    @property
    def full(self) -> bool:
        """The next ``append`` grows the columns."""
        return self.n_rows == self.capacity

    def append(self) -> int:
        """A new row holding a new point's initial values (zeros, an infinite maximum distance)."""
        if self.full:
            self._grow(2 * self.capacity)
        row = self.n_rows
        self.n_rows += 1
        return row

    def append_rows(self, n: int) -> tuple[int, int]:
        """Up to ``n`` new rows in one block (as many as fit, after growing the columns when they
        are full): (the first row, how many), each as ``append`` makes it."""
        if self.full:
            self._grow(2 * self.capacity)
        row = self.n_rows
        n = min(int(n), self.capacity - row)
        self.n_rows += n
        return row, n

    def _grow(self, capacity: int) -> None:
        for name, (shape, dtype, initial) in COLUMNS.items():
            old = getattr(self, name)
            new = np.full((capacity, *shape), initial, dtype=dtype)
            new[: len(old)] = old
            setattr(self, name, new)

    def compacted(self, rows: np.ndarray) -> PointStore:
        """A new store holding copies of ``rows`` (in that order, as rows 0, 1, ...), with room to grow."""
        out = PointStore(max(2 * len(rows), 1024))
        for name in COLUMNS:
            getattr(out, name)[: len(rows)] = getattr(self, name)[rows]
        out.n_rows = len(rows)
        return out
