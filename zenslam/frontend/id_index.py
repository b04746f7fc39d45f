"""Vectorised id -> row lookup: the rows of many point ids at once, without a Python loop.

The frontend's map stores points in rows and receives ids (in keyframes it made and in the
backend's map updates), thousands at a time. A dict looks ids up one Python call at a time; here the
ids are kept sorted with their rows, each batch of new ids is merged in (O(n) copying), and a lookup
is one ``np.searchsorted`` (benchmarks/frontend.md).
"""

from __future__ import annotations

import numpy as np


class IdIndex:
    """Sorted int64 ids with the row each one names; ids are unique and never negative."""

    def __init__(self) -> None:
        self._ids = np.zeros(0, dtype=np.int64)
        self._rows = np.zeros(0, dtype=np.int64)

    def __len__(self) -> int:
        return len(self._ids)

    @property
    def nbytes(self) -> int:
        """Bytes held by the sorted ids and their rows."""
        return self._ids.nbytes + self._rows.nbytes

    def add(self, ids: np.ndarray, rows: np.ndarray) -> None:
        """Record that each of ``ids`` (unique, not yet known, >= 0) lives in the matching row of ``rows``."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        rows = np.asarray(rows, dtype=np.int64).ravel()
        if ids.shape != rows.shape:
            raise ValueError(f"{len(ids)} ids but {len(rows)} rows")
        if len(ids) == 0:
            return
        order = np.argsort(ids, kind="stable")
        ids, rows = ids[order], rows[order]
        at = np.searchsorted(self._ids, ids)
        self._ids = np.insert(self._ids, at, ids)
        self._rows = np.insert(self._rows, at, rows)

    def rows(self, ids: np.ndarray) -> np.ndarray:
        """(N,) int64 rows of ``ids`` (any shape, flattened); -1 for ids never added (negative ones included)."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        if len(self._ids) == 0:
            return np.full(len(ids), -1, dtype=np.int64)
        at = np.minimum(np.searchsorted(self._ids, ids), len(self._ids) - 1)
        return np.where(self._ids[at] == ids, self._rows[at], -1)
