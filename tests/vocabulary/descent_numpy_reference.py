"""The vocabulary tree's descent as numpy did it, level by level, before its kernel (``vocabulary.descent``)."""

from __future__ import annotations

import numpy as np


def descend(vocabulary, d64: np.ndarray, node_level: int) -> tuple[np.ndarray, np.ndarray]:
    """``Vocabulary._descend``: (leaf of each descriptor, its node at ``node_level`` or its shallower leaf)."""
    v = vocabulary
    current = np.zeros(d64.shape[0], dtype=np.int64)
    at_level = current.copy()
    for level in range(1, v._height + 1):
        rows = v._inner_row[current]
        moving = np.flatnonzero(rows >= 0)
        if moving.size == 0:
            break
        if moving.size < rows.size:
            r = rows[moving]
            current[moving] = v._child_nodes[r, _nearest_child(v, d64[moving], r)]
        else:
            current = v._child_nodes[rows, _nearest_child(v, d64, rows)]
        if level == node_level:
            at_level = current.copy()
    if node_level > v._height:
        at_level = current
    elif node_level > 0:
        at_level = np.where(v._node_depth[current] < node_level, current, at_level)
    return current, at_level


def _nearest_child(v, d64: np.ndarray, rows: np.ndarray) -> np.ndarray:
    counts = np.bitwise_count(v._child_desc[rows] ^ d64[:, None, :])
    distance = (counts[..., 0] + counts[..., 1]).astype(np.int32) + (counts[..., 2] + counts[..., 3])
    return np.argmin(distance + v._child_penalty[rows], axis=1)
