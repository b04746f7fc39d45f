"""ORB-SLAM's quadtree distribution of FAST corners over an image region, compiled."""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel

_QUADTREE_DEPTH = 16  # deepest quadtree split: 2**16 nodes per side is far finer than a pixel


def distribute_quadtree(xy: np.ndarray, response: np.ndarray, width: int, height: int, n_target: int) -> np.ndarray:
    """Indices of the keypoints ORB-SLAM's quadtree keeps: one (the best response) per final node.

    ``xy`` (K, 2) float32 or float64 are pixel coordinates inside the region [0, width) x [0, height).
    As in ORB-SLAM's DistributeOctTree the region starts as round(width / height) nodes; every node
    holding more than one keypoint splits into four until there are at least ``n_target`` nodes or
    every node holds one keypoint, and when a full round would overshoot, the most populated nodes
    split first. (ORB-SLAM also stops when a round leaves the node count unchanged, which returns
    one keypoint for a cluster inside one quadrant; here such nodes keep splitting.)
    Nodes are addressed by Morton codes of the keypoints, so each round is a scan of the keypoints
    sorted once. Ties go to the lower Morton code, then the lower index: deterministic.
    Returns sorted int64 indices into ``xy``.
    """
    xy = np.asarray(xy)
    if xy.dtype != np.float32:
        xy = xy.astype(np.float64)
    if len(xy) == 0 or n_target <= 0:
        return np.zeros(0, np.int64)
    n_ini = max(1, int(round(width / height)))
    step = width / n_ini
    side = 1 << _QUADTREE_DEPTH
    # The node coordinates are computed in the coordinates' own precision where numpy would (a
    # float32 column divided by a Python float stays float32), so the codes do not depend on how
    # the caller stored them beyond that.
    scalar = xy.dtype.type
    code = _morton_codes(xy, n_ini, scalar(step), step, side / step, scalar(side / height))
    return _distribute(code, np.asarray(response), n_ini, n_target)


@kernel
def _spread_bits(v: int) -> int:
    """Interleave zeros between the 16 low bits of v (Morton encoding of one axis)."""
    v &= 0xFFFF
    v = (v | (v << 8)) & 0x00FF00FF
    v = (v | (v << 4)) & 0x0F0F0F0F
    v = (v | (v << 2)) & 0x33333333
    return (v | (v << 1)) & 0x55555555


@kernel
def _morton_codes(xy, n_ini, step, step64, scale_x, scale_y):
    """(K,) int64 code: initial node index above the interleaved 16-bit cell coordinates (y bit above x)."""
    side = 1 << _QUADTREE_DEPTH
    code = np.empty(len(xy), np.int64)
    for k in range(len(xy)):
        ini = min(max(np.int64(xy[k, 0] / step), 0), n_ini - 1)
        ix = min(max(np.int64((np.float64(xy[k, 0]) - ini * step64) * scale_x), 0), side - 1)
        iy = min(max(np.int64(xy[k, 1] * scale_y), 0), side - 1)
        code[k] = (ini << (2 * _QUADTREE_DEPTH)) | _spread_bits(ix) | (_spread_bits(iy) << 1)
    return code


@kernel
def _distribute(code, response, n_ini, n_target):
    order = np.argsort(code, kind="mergesort")
    code = code[order]
    n_keys = len(code)
    depth = 0
    while depth + 1 < _QUADTREE_DEPTH and n_ini * 4 ** (depth + 2) <= n_target:
        depth += 1  # depth + 1 has too few nodes for either stopping test: skip checking it
    starts = np.zeros(0, np.int64)
    while depth < _QUADTREE_DEPTH:
        depth += 1
        starts = _node_starts(code, depth)
        n_to_expand = 0
        for i in range(len(starts)):
            n_to_expand += _node_size(starts, i, n_keys) > 1
        if len(starts) >= n_target or n_to_expand == 0:
            break
        if len(starts) + 3 * n_to_expand > n_target:
            starts = _split_largest_first(code, starts, depth, n_target)
            break
    kept = np.empty(len(starts), np.int64)
    for i in range(len(starts)):
        best = starts[i]  # the first of the highest responses in the node
        for k in range(starts[i] + 1, starts[i] + _node_size(starts, i, n_keys)):
            if response[order[k]] > response[order[best]]:
                best = k
        kept[i] = order[best]
    return np.sort(kept)


@kernel
def _split_largest_first(code, starts, depth, n_target):
    """ORB-SLAM's last phase: split nodes, most keypoints first, until there are n_target nodes.

    ``starts`` are the first sorted-key index of each node, all nodes at ``depth`` (or single).
    Returns the final node starts.
    """
    n_keys = len(code)
    while depth < _QUADTREE_DEPTH:
        n_nodes = len(starts)
        sizes = np.empty(n_nodes, np.int64)
        for i in range(n_nodes):
            sizes[i] = _node_size(starts, i, n_keys)
        candidates = np.flatnonzero(sizes > 1)
        if len(candidates) == 0:
            return starts
        child_starts = _node_starts(code, depth + 1)
        n_children = np.zeros(n_nodes, np.int64)
        node = 0
        for start in child_starts:
            while node + 1 < n_nodes and starts[node + 1] <= start:
                node += 1
            n_children[node] += 1
        # most populated first; ties by position (ORB-SLAM breaks them by pointer value)
        candidates = candidates[np.argsort(-sizes[candidates], kind="mergesort")]
        wanted = n_target - n_nodes
        chosen = np.zeros(n_nodes, np.bool_)
        gained = 0
        for candidate in candidates:
            chosen[candidate] = True
            gained += n_children[candidate] - 1
            if gained >= wanted:
                break
        new_starts = np.empty(n_nodes + gained, np.int64)
        n_new = 0
        node = 0
        for start in child_starts:
            while node + 1 < n_nodes and starts[node + 1] <= start:
                node += 1
            if chosen[node] or start == starts[node]:
                new_starts[n_new] = start
                n_new += 1
        new_starts = new_starts[:n_new]
        if n_new >= n_target:
            return new_starts
        starts = new_starts
        depth += 1
    return starts


@kernel
def _node_starts(sorted_code, depth):
    """First index of each quadtree node at ``depth`` among keys sorted by Morton code."""
    shift = 2 * (_QUADTREE_DEPTH - depth)
    starts = np.empty(len(sorted_code), np.int64)
    n = 0
    previous = -1
    for k in range(len(sorted_code)):
        prefix = sorted_code[k] >> shift
        if k == 0 or prefix != previous:
            starts[n] = k
            n += 1
        previous = prefix
    return starts[:n]


@kernel
def _node_size(starts, i, n_keys):
    """Keys in node ``i``, from the nodes' first indices among ``n_keys`` sorted keys."""
    return (starts[i + 1] if i + 1 < len(starts) else n_keys) - starts[i]
