"""Matches between a monocular initialisation's reference frame and a later frame (ORB-SLAM's
``SearchForInitialization``).

Nothing is known about the motion yet, so every finest-level keypoint of the reference is looked
for in a square window around where it was last matched (its own position at first), among the
current frame's finest-level keypoints. A match is the nearest descriptor within ``max_distance``
bits and clearly nearer than the second (ratio test); one reference keypoint per current
keypoint (the nearest, then the lower reference index); then ORB-SLAM's rotation histogram keeps
the matches whose keypoint orientations turned alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.descriptors import hamming_distance_pairs
from zenslam.frontend.feature_matcher import rotation_consistent
from zenslam.frontend.frame import Frame


@dataclass(frozen=True)
class InitialisationMatchingConfig:
    """ORB-SLAM's monocular initialisation matching settings."""

    window_px: float = 100.0  # half side of the square searched around the last matched position, level-0 pixels
    max_distance: int = 50  # bits (ORB-SLAM TH_LOW)
    ratio: float = 0.9  # best distance must be below this times the second best
    check_orientation: bool = True  # ORB-SLAM's rotation histogram (30 bins, 3 largest kept)


def search_for_initialisation(
    reference: Frame, current: Frame, last_px: np.ndarray, config: InitialisationMatchingConfig = InitialisationMatchingConfig()
) -> np.ndarray:
    """Matches of ``reference``'s finest-level keypoints in ``current``.

    ``last_px`` (N, 2): per reference keypoint, where it was last matched (level-0 pixels; NaN for
    keypoints never to be searched). Returns (N,) int64: the current keypoint matched to each
    reference keypoint, -1 where none.
    """
    n_ref = reference.n_keypoints
    match = np.full(n_ref, -1, dtype=np.int64)
    last_px = np.asarray(last_px, dtype=np.float64).reshape(n_ref, 2)
    finest = reference.features.level == 0
    u = np.where(finest, last_px[:, 0], np.nan)
    v = np.where(finest, last_px[:, 1], np.nan)
    query, keypoint = current.indices_in_areas(u, v, config.window_px, 0, 0)
    if len(query) == 0:
        return match
    dist = hamming_distance_pairs(reference.features.descriptors[query], current.features.descriptors[keypoint]).astype(np.int64)
    # Per reference keypoint: nearest first (then the lower current index); its second nearest follows it.
    order = np.lexsort((keypoint, dist, query))
    query, keypoint, dist = query[order], keypoint[order], dist[order]
    first = np.flatnonzero(np.concatenate(([True], query[1:] != query[:-1])))
    has_second = np.diff(np.append(first, len(query))) > 1
    second_dist = np.where(has_second, dist[np.minimum(first + 1, len(dist) - 1)], np.iinfo(np.int64).max)
    best_q, best_k, best_d = query[first], keypoint[first], dist[first]
    ok = (best_d <= config.max_distance) & (best_d < config.ratio * second_dist)
    best_q, best_k, best_d = best_q[ok], best_k[ok], best_d[ok]
    # One reference keypoint per current keypoint: the nearest, then the lower reference index.
    order = np.lexsort((best_q, best_d, best_k))
    best_q, best_k = best_q[order], best_k[order]
    winner = np.concatenate(([True], best_k[1:] != best_k[:-1])) if len(best_k) else np.zeros(0, dtype=bool)
    best_q, best_k = best_q[winner], best_k[winner]
    if config.check_orientation and len(best_q):
        turn = reference.features.angle_deg[best_q].astype(np.float64) - current.features.angle_deg[best_k].astype(np.float64)
        keep = rotation_consistent(turn)
        best_q, best_k = best_q[keep], best_k[keep]
    match[best_q] = best_k
    return match
