"""The numpy formulation of the ORB extractor's quadtree and intensity centroid, the reference its compiled kernels must equal bit for bit.

tests/frontend/test_orb_kernels.py compares them; benchmarks/compiled_kernels.py times one against the other.
"""

from __future__ import annotations

import numpy as np

from zenslam.frontend.orb_orientation import disc_half_widths

_DEPTH = 16
_HALF_PATCH = 15


def reference_quadtree(xy, response, width, height, n_target):
    """distribute_quadtree as numpy vector operations over the Morton-sorted codes."""
    n_keys = len(xy)
    if n_keys == 0 or n_target <= 0:
        return np.zeros(0, np.int64)
    n_ini = max(1, int(round(width / height)))
    step = width / n_ini
    side = 1 << _DEPTH
    ini = np.minimum(np.maximum((xy[:, 0] / step).astype(np.int64), 0), n_ini - 1)
    ix = np.minimum(np.maximum(((xy[:, 0] - ini * step) * (side / step)).astype(np.int64), 0), side - 1)
    iy = np.minimum(np.maximum((xy[:, 1] * (side / height)).astype(np.int64), 0), side - 1)
    code = (ini << (2 * _DEPTH)) | _spread_bits(ix) | (_spread_bits(iy) << 1)
    order = np.argsort(code)  # codes of distinct pixels differ: the result does not depend on ties
    code = code[order]
    depth = 0
    while depth + 1 < _DEPTH and n_ini * 4 ** (depth + 2) <= n_target:
        depth += 1
    while depth < _DEPTH:
        depth += 1
        starts = np.flatnonzero(_node_start_mask(code, depth))
        n_to_expand = int(np.count_nonzero(_node_sizes(starts, n_keys) > 1))
        if len(starts) >= n_target or n_to_expand == 0:
            break
        if len(starts) + 3 * n_to_expand > n_target:
            starts = _split_largest_first(code, starts, depth, n_target)
            break
    return np.sort(order[_best_per_node(response[order], starts)])


def _split_largest_first(code, starts, depth, n_target):
    n_keys = len(code)
    while depth < _DEPTH:
        sizes = _node_sizes(starts, n_keys)
        candidates = np.flatnonzero(sizes > 1)
        if len(candidates) == 0:
            return starts
        is_child_start = _node_start_mask(code, depth + 1)
        n_children = np.add.reduceat(is_child_start, starts, dtype=np.int64)
        candidates = candidates[np.argsort(-sizes[candidates], kind="stable")]
        reached = np.flatnonzero(np.cumsum(n_children[candidates] - 1) >= n_target - len(starts))
        chosen = candidates if len(reached) == 0 else candidates[: reached[0] + 1]
        in_chosen = np.zeros(len(starts), bool)
        in_chosen[chosen] = True
        is_child_start &= np.repeat(in_chosen, sizes)
        is_child_start[starts] = True
        new_starts = np.flatnonzero(is_child_start)
        if len(new_starts) >= n_target:
            return new_starts
        starts = new_starts
        depth += 1
    return starts


def _node_start_mask(sorted_code, depth):
    prefix = sorted_code >> (2 * (_DEPTH - depth))
    change = np.empty(len(prefix), bool)
    change[0] = True
    np.not_equal(prefix[1:], prefix[:-1], out=change[1:])
    return change


def _node_sizes(starts, n_keys):
    sizes = np.empty(len(starts), np.int64)
    np.subtract(starts[1:], starts[:-1], out=sizes[:-1])
    sizes[-1] = n_keys - starts[-1]
    return sizes


def _best_per_node(response, starts):
    sizes = _node_sizes(starts, len(response))
    best = np.maximum.reduceat(response, starts)
    candidates = np.flatnonzero(response == np.repeat(best, sizes))
    node = np.repeat(np.arange(len(starts)), sizes)[candidates]
    first = np.ones(len(candidates), bool)
    np.not_equal(node[1:], node[:-1], out=first[1:])
    return candidates[first]


_SPREAD_BYTE = np.array([sum(((v >> bit) & 1) << (2 * bit) for bit in range(8)) for v in range(256)], np.int64)


def _spread_bits(v):
    return _SPREAD_BYTE[v & 0xFF] | (_SPREAD_BYTE[(v >> 8) & 0xFF] << 16)


def reference_angles(image, xy):
    """intensity_centroid_angles as a float32 einsum of the 31x31 windows with the disc's weights."""
    u_max = disc_half_widths()
    offsets = np.arange(-_HALF_PATCH, _HALF_PATCH + 1)
    v_grid, u_grid = np.meshgrid(offsets, offsets, indexing="ij")
    inside = np.abs(u_grid) <= u_max[np.abs(v_grid)]
    weights = np.stack([(u_grid * inside).reshape(-1), (v_grid * inside).reshape(-1)]).astype(np.float32)
    cols = np.rint(xy[:, 0]).astype(np.int64) - _HALF_PATCH
    rows = np.rint(xy[:, 1]).astype(np.int64) - _HALF_PATCH
    step_y, step_x = image.strides
    shape = (image.shape[0] - 30, image.shape[1] - 30, 31, 31)
    windows = np.lib.stride_tricks.as_strided(image, shape, (step_y, step_x, step_y, step_x), writeable=False)[rows, cols]
    moments = np.einsum("nk,ck->nc", windows.reshape(len(xy), -1).astype(np.float32), weights)
    angle = np.degrees(np.arctan2(moments[:, 1], moments[:, 0]))
    return np.mod(angle, 360.0).astype(np.float32)
