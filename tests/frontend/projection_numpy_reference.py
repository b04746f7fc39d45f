"""The numpy formulation of search by projection, kept as the reference the compiled kernels
(zenslam/frontend/projection_matching.py) must equal exactly."""

from __future__ import annotations

import numpy as np

from zenslam.descriptors import hamming_distance_pairs


def search_by_projection(
    proj_px: np.ndarray,
    predicted_level: np.ndarray,
    point_desc: np.ndarray,
    kp_px: np.ndarray,
    kp_level: np.ndarray,
    kp_desc: np.ndarray,
    radius_px: float | np.ndarray,
    max_distance: int = 100,
    ratio: float | None = 0.8,
    already_matched: np.ndarray | None = None,
    min_level_offset: int | None = -1,
    max_level_offset: int | None = 0,
    kp_right_u: np.ndarray | None = None,
    proj_right_u: np.ndarray | None = None,
    max_passes: int = 4,
) -> np.ndarray:
    """``zenslam.frontend.feature_matcher.search_by_projection`` as numpy pair arrays (its docstring states the rules)."""
    proj_px = np.asarray(proj_px, dtype=float).reshape(-1, 2)
    kp_px = np.asarray(kp_px, dtype=float).reshape(-1, 2)
    m, n = len(proj_px), len(kp_px)
    radius = np.broadcast_to(np.asarray(radius_px, dtype=float), (m,))
    match = np.full(m, -1, dtype=np.int32)
    if m == 0 or n == 0:
        return match
    proj_idx, kp_idx = _candidates_in_windows(proj_px, radius, kp_px)
    predicted_level = np.asarray(predicted_level, dtype=np.int64).reshape(m)
    kp_level = np.asarray(kp_level, dtype=np.int64).reshape(n)
    keep = _level_window(kp_level[kp_idx], predicted_level[proj_idx], min_level_offset, max_level_offset)
    if already_matched is not None:
        keep &= ~np.asarray(already_matched, dtype=bool).reshape(n)[kp_idx]
    if kp_right_u is not None and proj_right_u is not None:
        kp_ur = np.asarray(kp_right_u, dtype=float).reshape(n)[kp_idx]
        proj_ur = np.asarray(proj_right_u, dtype=float).reshape(m)[proj_idx]
        has_right = np.isfinite(kp_ur) & (kp_ur >= 0)
        keep &= ~has_right | (np.abs(proj_ur - kp_ur) < radius[proj_idx])
    proj_idx, kp_idx = proj_idx[keep], kp_idx[keep]
    dist = hamming_distance_pairs(np.asarray(point_desc)[proj_idx], np.asarray(kp_desc)[kp_idx])
    return _assign_one_to_one(match, proj_idx, kp_idx, dist, kp_level, max_distance, ratio, max_passes)


def _candidates_in_windows(proj_px: np.ndarray, radius: np.ndarray, kp_px: np.ndarray):
    """All (projection, keypoint) pairs with |du| < r and |dv| < r, as two index arrays.

    Keypoints are bucketed once into horizontal stripes and sorted by u inside each stripe, so a
    window is a few contiguous runs found by binary search: no per-projection Python loop.
    """
    n_kp = len(kp_px)
    u, v = kp_px[:, 0], kp_px[:, 1]
    u0, v0 = float(u.min()), float(v.min())
    width = float(u.max()) - u0
    finite_r = radius[np.isfinite(radius) & (radius > 0)]
    stripe_h = max(float(np.median(finite_r)) if finite_r.size else 1.0, 1.0)
    n_stripes = int((float(v.max()) - v0) // stripe_h) + 1
    stripe = ((v - v0) // stripe_h).astype(np.int64)
    # One sortable key per keypoint: stripe-major, then u; span > width keeps stripes apart.
    span = width + 2.0
    key = stripe * span + (u - u0)
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]

    valid = np.isfinite(proj_px).all(axis=1) & np.isfinite(radius) & (radius > 0)
    pu, pv, r = proj_px[valid, 0] - u0, proj_px[valid, 1] - v0, radius[valid]
    s_lo = np.clip(np.floor((pv - r) / stripe_h), 0, n_stripes).astype(np.int64)
    s_hi = np.clip(np.floor((pv + r) / stripe_h), -1, n_stripes - 1).astype(np.int64)
    n_s = np.maximum(s_hi - s_lo + 1, 0)
    query = np.repeat(np.flatnonzero(valid), n_s)
    q_pos = np.repeat(np.arange(len(pu)), n_s)
    q_stripe = np.repeat(s_lo - _starts(n_s), n_s) + np.arange(int(n_s.sum()))
    lo = np.searchsorted(key_sorted, q_stripe * span + np.clip(pu[q_pos] - r[q_pos], -0.5, span - 1.0), "right")
    hi = np.searchsorted(key_sorted, q_stripe * span + np.clip(pu[q_pos] + r[q_pos], -0.5, span - 1.0), "left")
    count = np.maximum(hi - lo, 0)
    proj_idx = np.repeat(query, count)
    kp_idx = order[np.repeat(lo - _starts(count), count) + np.arange(int(count.sum()))]
    offset = np.abs(kp_px[kp_idx] - proj_px[proj_idx])  # exact square window; stripes are coarse
    inside = (offset < radius[proj_idx, None]).all(axis=1)
    return proj_idx[inside], kp_idx[inside]


def _starts(counts: np.ndarray) -> np.ndarray:
    """Start offset of each run in the concatenation of runs of the given lengths."""
    return np.concatenate(([0], np.cumsum(counts)[:-1])) if len(counts) else counts


def _level_window(kp_level, predicted, min_offset: int | None, max_offset: int | None) -> np.ndarray:
    keep = np.ones(len(kp_level), dtype=bool)
    if min_offset is not None:
        keep &= kp_level >= predicted + min_offset
    if max_offset is not None:
        keep &= kp_level <= predicted + max_offset
    return keep


def _assign_one_to_one(match, proj_idx, kp_idx, dist, kp_level, max_distance, ratio, max_passes):
    """Best keypoint per projection (ratio test, threshold), then one projection per keypoint."""
    n_kp, n_proj = len(kp_level), len(match)
    taken = np.zeros(n_kp, dtype=bool)
    for _ in range(max(max_passes, 1)):
        alive = (match[proj_idx] < 0) & ~taken[kp_idx]
        p, k, d = proj_idx[alive], kp_idx[alive], dist[alive]
        if len(p) == 0:
            break
        # Per projection: distance, then keypoint index (one int64 key sorts faster than lexsort).
        order = np.argsort((p * 257 + d) * n_kp + k, kind="stable")
        p, k, d = p[order], k[order], d[order]
        first = np.concatenate(([True], p[1:] != p[:-1]))
        best = np.flatnonzero(first)
        has_second = np.diff(np.append(best, len(p))) > 1
        second = np.where(has_second, best + 1, best)
        ok = d[best] <= max_distance
        if ratio is not None:
            same_level = has_second & (kp_level[k[best]] == kp_level[k[second]])
            ok &= ~(same_level & (d[best] > ratio * d[second]))
        bp, bk, bd = p[best][ok], k[best][ok], d[best][ok]
        if len(bp) == 0:
            break
        # One projection per keypoint: smallest distance, then lowest projection index.
        order = np.argsort((bk * 257 + bd) * n_proj + bp, kind="stable")
        bp, bk = bp[order], bk[order]
        winner = np.concatenate(([True], bk[1:] != bk[:-1]))
        match[bp[winner]] = bk[winner]
        taken[bk[winner]] = True
        if winner.all():
            break
    return match
