"""Fusion's search by projection, compiled: the best keypoint for each projected map point (``Fuse``).

``point_fusion.match_projected`` states the rules: the keypoints strictly inside a square window
around the projection, at the predicted level or one below, whose reprojection error passes the
chi-square gate of their level; of those, the one with the smallest descriptor distance (then the
lowest index), if within the threshold. This kernel scans each window's keypoints in u order once
instead of numpy's arrays of every pair. The tests compare the caller's numbers, and the
reprojection error is summed in numpy's formulation's order (no fastmath), so the choice is the
same on any x86-64 CPU; distances are integers.
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel
from zenslam.descriptor_words import distance


@kernel
def best_in_windows(
    rows, u, v, radius, predicted, proj_right_u, lo, hi, order, kp_px, kp_level, kp_right_u, level_sigma2,
    chi2_mono, chi2_stereo, point_words, kp_words, max_distance,
):  # fmt: skip
    """(M,) int64: the keypoint matched to projection m, or -1.

    Projection m (of point row ``rows[m]``, at (``u[m]``, ``v[m]``), right-image u ``proj_right_u[m]``,
    predicted level ``predicted[m]``, window half-side ``radius[m]``) is tested against the keypoints
    ``order[lo[m]:hi[m]]`` (those with u strictly inside the window, ``order`` sorting them by u).
    A keypoint with a right-image u (>= 0) adds the squared difference to the projection's (NaN
    read as 0) to its error.
    """
    n = len(rows)
    best = np.full(n, -1, np.int64)
    for m in range(n):
        r = radius[m]
        right = proj_right_u[m]
        if np.isnan(right):
            right = 0.0
        elif np.isinf(right):
            right = np.finfo(np.float64).max if right > 0 else -np.finfo(np.float64).max
        best_distance = max_distance + 1
        for slot in range(lo[m], hi[m]):
            k = order[slot]
            dv = kp_px[k, 1] - v[m]
            level = kp_level[k]
            if not (abs(dv) < r and level >= predicted[m] - 1 and level <= predicted[m]):
                continue
            du = kp_px[k, 0] - u[m]
            err2 = du * du + dv * dv
            stereo = kp_right_u[k] >= 0
            if stereo:
                dr = right - kp_right_u[k]
                err2 = err2 + dr * dr
            else:
                err2 = err2 + 0.0
            scaled = err2 * (1.0 / level_sigma2[level])
            if not (scaled <= chi2_stereo if stereo else scaled <= chi2_mono):
                continue
            d = distance(point_words, rows[m], kp_words, k)
            if d < best_distance or (d == best_distance and k < best[m]):
                best_distance = d
                best[m] = k
    return best
