"""Descriptor matching over plain arrays: search by projection, rotation consistency, brute force.

These are ORB-SLAM's ``ORBmatcher`` primitives without the frame and map-point classes, so they
work on whatever arrays the tracker holds. Pixels are level-0 pixels of the current (left) image,
levels are ORB pyramid octaves, descriptors are 256-bit ORB descriptors (32 uint8) compared by
Hamming distance. Every result is deterministic: ties go to the lower index.
"""

from __future__ import annotations

import cv2
import numpy as np


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
    """Match projected map points to keypoints in a window around each projection.

    proj_px: (M, 2) predicted level-0 pixels of the map points in the current image.
    predicted_level: (M,) int predicted pyramid level of each map point.
    point_desc: (M, 32) uint8 map-point descriptors; kp_px (N, 2), kp_level (N,), kp_desc (N, 32)
    the current keypoints.
    radius_px: half-width of the square search window in level-0 pixels, scalar or (M,); the
    caller folds in ORB-SLAM's ``th`` and the scale factor of the predicted level.
    max_distance: accept a best match at most this many bits away (ORB-SLAM TH_HIGH = 100).
    ratio: reject when best > ratio * second best and both lie on the same level, as ORB-SLAM's
    local-map search; ``None`` disables the test (ORB-SLAM's motion-model search).
    already_matched: (N,) bool keypoints that are not candidates.
    min_level_offset / max_level_offset: keypoint levels allowed relative to the predicted level,
    inclusive; ``None`` leaves that side open (local map: -1, 0; motion model: -1, +1).
    kp_right_u (N,) / proj_right_u (M,): right-image u in pixels; when both are given, a keypoint
    with right_u >= 0 must also satisfy |proj_right_u - kp_right_u| < radius (stereo check).
    max_passes: how many times projections that lost their keypoint to a better match search
    again among the keypoints still free (1 = never).

    Returns (M,) int32: the matched keypoint index, or -1. Each keypoint is matched at most once:
    the projection with the smaller distance wins (then the lower index), and a loser searches
    again among the keypoints still free.
    """
    # The kernels import numba (~60 MB and most of a second per process): only a process that
    # searches loads it, not every one that imports the tracking configs.
    from zenslam.descriptor_words import words
    from zenslam.frontend.projection_matching import search_in_windows

    proj_px = np.ascontiguousarray(proj_px, dtype=float).reshape(-1, 2)
    kp_px = np.ascontiguousarray(kp_px, dtype=float).reshape(-1, 2)
    m, n = len(proj_px), len(kp_px)
    if m == 0 or n == 0:
        return np.full(m, -1, dtype=np.int32)
    free = np.ones(n, dtype=bool) if already_matched is None else ~np.asarray(already_matched, dtype=bool).reshape(n)
    use_right = kp_right_u is not None and proj_right_u is not None
    return search_in_windows(
        proj_px,
        np.ascontiguousarray(np.broadcast_to(np.asarray(radius_px, dtype=float), (m,))),
        np.ascontiguousarray(predicted_level, dtype=np.int64).reshape(m),
        words(point_desc),
        kp_px,
        np.ascontiguousarray(kp_level, dtype=np.int64).reshape(n),
        words(kp_desc),
        free,
        np.ascontiguousarray(proj_right_u, dtype=float).reshape(m) if use_right else None,
        np.ascontiguousarray(kp_right_u, dtype=float).reshape(n) if use_right else None,
        min_level_offset,
        max_level_offset,
        max_distance,
        ratio,
        max_passes,
    )


def rotation_consistent(angle_diff_deg: np.ndarray, n_bins: int = 30, keep_bins: int = 3) -> np.ndarray:
    """ORB-SLAM's rotation histogram: keep matches whose keypoint-angle change is in a dominant bin.

    angle_diff_deg: (K,) reference angle minus current angle of each match, degrees (any range).
    The K differences go into ``n_bins`` bins over 360 degrees; the ``keep_bins`` fullest bins are
    kept, except that the second and third are dropped when they hold less than a tenth of the
    first (ORB-SLAM's ComputeThreeMaxima). Returns (K,) bool; non-finite differences are False.
    """
    diff = np.asarray(angle_diff_deg, dtype=float).reshape(-1)
    finite = np.isfinite(diff)
    out = np.zeros(len(diff), dtype=bool)
    if not finite.any():
        return out
    bins = np.rint(np.mod(diff[finite], 360.0) * (n_bins / 360.0)).astype(np.int64) % n_bins
    counts = np.bincount(bins, minlength=n_bins)
    ranked = np.argsort(-counts, kind="stable")[:keep_bins]  # ties: lower bin first, as ORB-SLAM
    kept = [ranked[0]]
    for b in ranked[1:]:
        if counts[b] < 0.1 * counts[ranked[0]]:
            break  # ORB-SLAM drops the third bin whenever it drops the second
        kept.append(b)
    out[finite] = np.isin(bins, kept)
    return out


def match_by_descriptor(
    desc_a: np.ndarray, desc_b: np.ndarray, max_distance: int = 50, ratio: float | None = 0.7
) -> np.ndarray:
    """Brute-force one-to-one matching of descriptors a (N, 32) to b (M, 32), uint8.

    For each row of a, the nearest row of b is accepted if its Hamming distance is at most
    ``max_distance`` bits (ORB-SLAM TH_LOW = 50) and strictly below ``ratio`` times the second nearest (ORB-SLAM's
    SearchByBoW rule; ``None`` disables the ratio test). When several rows of a pick the same row
    of b, the nearest wins (then the lower index of a). Returns (K, 2) int64 pairs (i in a, j in b)
    sorted by i.
    """
    a = np.ascontiguousarray(desc_a, dtype=np.uint8).reshape(-1, 32)
    b = np.ascontiguousarray(desc_b, dtype=np.uint8).reshape(-1, 32)
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    # OpenCV's batchDistance keeps the two nearest per row (ties: lower index) without building the
    # N x M distance matrix that numpy would need.
    k = min(2, len(b))
    dist, nearest = cv2.batchDistance(a, b, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=k)
    best_d, best_j = dist[:, 0].astype(np.int64), nearest[:, 0].astype(np.int64)
    ok = best_d <= max_distance
    if ratio is not None and k == 2:
        ok &= best_d < ratio * dist[:, 1]
    i = np.flatnonzero(ok)
    j, d = best_j[ok], best_d[ok]
    order = np.lexsort((i, d, j))
    i, j = i[order], j[order]
    winner = np.concatenate(([True], j[1:] != j[:-1])) if len(j) else np.zeros(0, dtype=bool)
    pairs = np.stack([i[winner], j[winner]], axis=1)
    return pairs[np.argsort(pairs[:, 0], kind="stable")]
