"""Search by projection, compiled: the keypoints in a window around each projected map point, and
the one-to-one assignment of projections to keypoints by descriptor distance.

``feature_matcher.search_by_projection`` states the rules; these kernels apply them in one pass
over the candidates instead of numpy's sorted pair arrays. Keypoints are bucketed into a grid of
square cells once; each projection scans the cells its window touches (one cell more on each side,
so rounding never hides a keypoint) and keeps the keypoints strictly inside the window.
Distances are Hamming distances of the 256-bit descriptors as four 64-bit words. Every choice is
an exact comparison of the caller's numbers or of integers, so the result is the same on any CPU.
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel
from zenslam.descriptor_words import popcount

_NO_LEVEL_BOUND = np.iinfo(np.int64).max  # a level offset that admits every level
_NO_RIGHT_U = np.zeros(0)  # the right-image u arrays of a search without the stereo check (never read)
_MIN_CELL_PX = 8.0  # level-0 pixels: the smallest side of the keypoint grid's cells


def search_in_windows(
    proj_px: np.ndarray,
    radius: np.ndarray,
    predicted_level: np.ndarray,
    point_words: np.ndarray,
    kp_px: np.ndarray,
    kp_level: np.ndarray,
    kp_words: np.ndarray,
    free: np.ndarray,
    proj_right_u: np.ndarray | None,
    kp_right_u: np.ndarray | None,
    min_level_offset: int | None,
    max_level_offset: int | None,
    max_distance: int,
    ratio: float | None,
    max_passes: int,
) -> np.ndarray:
    """(M,) int32 keypoint matched to each projection, or -1 (see ``search_by_projection``).

    ``point_words`` (M, 4) and ``kp_words`` (N, 4) are the descriptors as uint64 words; ``free``
    (N,) bool the keypoints that may be matched; the right-image u arrays go together or not at all.
    """
    # Any cell size gives the same candidates; about a window's width keeps both the grid and the
    # scan per projection small.
    finite = radius[np.isfinite(radius) & (radius > 0)]
    cell_px = max(float(np.median(finite)) if finite.size else _MIN_CELL_PX, _MIN_CELL_PX)
    use_right = proj_right_u is not None and kp_right_u is not None
    candidates, distances, starts = _candidates(
        proj_px, radius, predicted_level, point_words, kp_px, kp_level, kp_words, free,
        proj_right_u if use_right else _NO_RIGHT_U, kp_right_u if use_right else _NO_RIGHT_U, use_right,
        _NO_LEVEL_BOUND if min_level_offset is None else -int(min_level_offset),
        _NO_LEVEL_BOUND if max_level_offset is None else int(max_level_offset),
        cell_px,
    )  # fmt: skip
    return _assign(
        candidates, distances, starts, kp_level, len(kp_px), int(max_distance),
        ratio is not None, 0.0 if ratio is None else float(ratio), max(int(max_passes), 1),
    )  # fmt: skip


@kernel
def _candidates(
    proj_px, radius, predicted_level, point_words, kp_px, kp_level, kp_words, free,
    proj_right_u, kp_right_u, use_right, below_levels, above_levels, cell_px,
):  # fmt: skip
    """Each projection's candidate keypoints and their distances, as runs: projection p's are
    ``candidates[starts[p]:starts[p + 1]]``, in the order its cells were scanned."""
    n_proj, n_kp = len(proj_px), len(kp_px)
    u0, v0 = kp_px[0, 0], kp_px[0, 1]
    u1, v1 = u0, v0
    for k in range(n_kp):
        u0, u1 = min(u0, kp_px[k, 0]), max(u1, kp_px[k, 0])
        v0, v1 = min(v0, kp_px[k, 1]), max(v1, kp_px[k, 1])
    n_cols = np.int64((u1 - u0) / cell_px) + 1
    n_rows = np.int64((v1 - v0) / cell_px) + 1
    # keypoints by cell (CSR), ascending within a cell
    cell_of = np.empty(n_kp, np.int64)
    cell_count = np.zeros(n_rows * n_cols + 1, np.int64)
    for k in range(n_kp):
        col = min(np.int64((kp_px[k, 0] - u0) / cell_px), n_cols - 1)
        row = min(np.int64((kp_px[k, 1] - v0) / cell_px), n_rows - 1)
        cell_of[k] = row * n_cols + col
        cell_count[cell_of[k] + 1] += 1
    cell_start = np.cumsum(cell_count)
    fill = cell_start[:-1].copy()
    by_cell = np.empty(n_kp, np.int64)
    for k in range(n_kp):
        by_cell[fill[cell_of[k]]] = k
        fill[cell_of[k]] += 1

    starts = np.zeros(n_proj + 1, np.int64)
    capacity = max(4 * n_proj, 16)
    candidates = np.empty(capacity, np.int64)
    distances = np.empty(capacity, np.int64)
    n_found = 0
    for p in range(n_proj):
        pu, pv, r = proj_px[p, 0], proj_px[p, 1], radius[p]
        if np.isfinite(pu) and np.isfinite(pv) and np.isfinite(r) and r > 0:
            col_lo = max(np.int64(np.floor((pu - r - u0) / cell_px)) - 1, 0)
            col_hi = min(np.int64(np.floor((pu + r - u0) / cell_px)) + 1, n_cols - 1)
            row_lo = max(np.int64(np.floor((pv - r - v0) / cell_px)) - 1, 0)
            row_hi = min(np.int64(np.floor((pv + r - v0) / cell_px)) + 1, n_rows - 1)
            for row in range(row_lo, row_hi + 1):
                for col in range(col_lo, col_hi + 1):
                    cell = row * n_cols + col
                    for slot in range(cell_start[cell], cell_start[cell + 1]):
                        k = by_cell[slot]
                        if not free[k]:
                            continue
                        if not (abs(kp_px[k, 0] - pu) < r and abs(kp_px[k, 1] - pv) < r):
                            continue
                        offset = kp_level[k] - predicted_level[p]
                        if offset < -below_levels or offset > above_levels:
                            continue
                        if use_right:
                            right = kp_right_u[k]
                            if np.isfinite(right) and right >= 0 and not abs(proj_right_u[p] - right) < r:
                                continue
                        if n_found == capacity:
                            capacity *= 2
                            candidates = _grown(candidates, capacity)
                            distances = _grown(distances, capacity)
                        d = np.int64(0)
                        for w in range(4):
                            d += popcount(point_words[p, w] ^ kp_words[k, w])
                        candidates[n_found] = k
                        distances[n_found] = d
                        n_found += 1
        starts[p + 1] = n_found
    return candidates[:n_found], distances[:n_found], starts


@kernel
def _grown(values, capacity):
    out = np.empty(capacity, values.dtype)
    out[: len(values)] = values
    return out


@kernel
def _assign(candidates, distances, starts, kp_level, n_kp, max_distance, use_ratio, ratio, max_passes):
    """Best keypoint per projection (threshold, ratio test on one level), then one projection per
    keypoint (the smaller distance, then the lower projection index); a projection that lost its
    keypoint searches again among the keypoints still free, up to ``max_passes`` rounds."""
    n_proj = len(starts) - 1
    match = np.full(n_proj, -1, np.int32)
    taken = np.zeros(n_kp, np.bool_)
    best_k = np.empty(n_proj, np.int64)
    best_d = np.empty(n_proj, np.int64)
    winner_p = np.full(n_kp, -1, np.int64)
    winner_d = np.zeros(n_kp, np.int64)
    for _ in range(max_passes):
        n_alive = 0
        n_ok = 0
        for p in range(n_proj):
            best_k[p] = -1
            if match[p] >= 0:
                continue
            k1, d1, k2, d2 = -1, 0, -1, 0  # best and second by (distance, keypoint)
            for i in range(starts[p], starts[p + 1]):
                k = candidates[i]
                if taken[k]:
                    continue
                d = distances[i]
                n_alive += 1
                if k1 < 0 or d < d1 or (d == d1 and k < k1):
                    k2, d2 = k1, d1
                    k1, d1 = k, d
                elif k2 < 0 or d < d2 or (d == d2 and k < k2):
                    k2, d2 = k, d
            if k1 < 0 or d1 > max_distance:
                continue
            if use_ratio and k2 >= 0 and kp_level[k1] == kp_level[k2] and d1 > ratio * d2:
                continue
            best_k[p] = k1
            best_d[p] = d1
            n_ok += 1
        if n_alive == 0 or n_ok == 0:
            break
        n_won = 0
        for p in range(n_proj):  # ascending: on equal distances the lower projection stays
            k = best_k[p]
            if k >= 0 and (winner_p[k] < 0 or best_d[p] < winner_d[k]):
                if winner_p[k] < 0:
                    n_won += 1
                winner_p[k] = p
                winner_d[k] = best_d[p]
        for p in range(n_proj):
            k = best_k[p]
            if k >= 0 and winner_p[k] == p:
                match[p] = k
                taken[k] = True
        for p in range(n_proj):
            if best_k[p] >= 0:
                winner_p[best_k[p]] = -1
        if n_won == n_ok:
            break
    return match
