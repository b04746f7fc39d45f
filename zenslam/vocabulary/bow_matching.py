"""Descriptor matching guided by the vocabulary's direct index: ORB-SLAM's SearchByBoW between two images.

Only descriptors under the same vocabulary node (of the FeatureVectors) are compared, which makes
matching two keyframes' ~1,000 features cheap without any pose. Within a node each usable feature
of image a takes its nearest usable, still unmatched feature of image b, if that is close enough
and clearly better than the second nearest; nodes and features are visited in ascending order, so
the result is deterministic. A rotation histogram then keeps the matches whose change of keypoint
orientation agrees with the dominant ones.
"""

from __future__ import annotations

import itertools

import numpy as np

from zenslam.descriptors import hamming_distance
from zenslam.vocabulary.bow import FeatureVector

HISTOGRAM_BINS = 30  # bins of the rotation histogram over 360 degrees (ORB-SLAM's HISTO_LENGTH)
_SECONDARY_FRACTION = 0.1  # a second/third histogram peak counts only with >= this fraction of the one above it


def search_by_bow(
    fvec_a: FeatureVector,
    desc_a: np.ndarray,
    angles_a_deg: np.ndarray,
    fvec_b: FeatureVector,
    desc_b: np.ndarray,
    angles_b_deg: np.ndarray,
    usable_a: np.ndarray | None = None,
    usable_b: np.ndarray | None = None,
    max_distance: int = 50,
    ratio: float = 0.75,
    check_orientation: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Matched feature indices (idx_a, idx_b), int64, one-to-one, sorted by idx_a.

    ``desc_*`` (N, 32) uint8 descriptors and ``angles_*_deg`` (N,) keypoint orientations (degrees)
    of the features that ``fvec_*`` index; ``usable_*`` (N,) bool masks of the features that may
    match (e.g. those with a map point), None for all. A feature of a matches its nearest
    feature of b when their Hamming distance is below ``max_distance`` (ORB-SLAM's TH_LOW: 50) and
    below ``ratio`` times the second nearest's (256 when there is none). With
    ``check_orientation``, matches outside the three largest bins of the histogram of orientation
    changes (30 bins) are dropped.
    """
    usable_a = np.ones(len(desc_a), dtype=bool) if usable_a is None else np.asarray(usable_a, dtype=bool)
    usable_b = np.ones(len(desc_b), dtype=bool) if usable_b is None else np.asarray(usable_b, dtype=bool)
    _, in_a, in_b = np.intersect1d(fvec_a.node_ids, fvec_b.node_ids, assume_unique=True, return_indices=True)
    matched_b = bytearray(len(desc_b))
    pairs_a: list[int] = []
    pairs_b: list[int] = []
    for node_a, node_b in zip(in_a.tolist(), in_b.tolist()):
        features_a = fvec_a.features[node_a]
        features_a = features_a[usable_a[features_a]]
        features_b = fvec_b.features[node_b]
        features_b = features_b[usable_b[features_b]]
        if features_a.size == 0 or features_b.size == 0:
            continue
        candidates = features_b.tolist()
        # Plain Python over the few features of one node: the greedy order (an earlier feature of a
        # takes its match first) is what ORB-SLAM does, and small lists beat per-row numpy calls.
        for i, row in zip(features_a.tolist(), hamming_distance(desc_a[features_a], desc_b[features_b]).tolist()):
            best, second, best_j = 256, 256, -1
            for j, distance in zip(candidates, row):
                if matched_b[j]:
                    continue
                if distance < best:
                    second, best, best_j = best, distance, j
                elif distance < second:
                    second = distance
            if best < max_distance and best < ratio * second:
                matched_b[best_j] = 1
                pairs_a.append(i)
                pairs_b.append(best_j)
    idx_a = np.array(pairs_a, dtype=np.int64)
    idx_b = np.array(pairs_b, dtype=np.int64)
    if check_orientation and idx_a.size:
        keep = rotation_consistent(
            np.asarray(angles_a_deg, dtype=np.float64)[idx_a] - np.asarray(angles_b_deg, dtype=np.float64)[idx_b]
        )
        idx_a, idx_b = idx_a[keep], idx_b[keep]
    order = np.argsort(idx_a, kind="stable")
    return idx_a[order], idx_b[order]


def rotation_consistent(rotation_deg: np.ndarray) -> np.ndarray:
    """Mask of the orientation changes (degrees) that fall in the three largest histogram bins.

    As ORB-SLAM's ComputeThreeMaxima: bins of 12 degrees, rounded to the nearest bin (360 wraps to
    0); the second and third largest count only if they hold at least a tenth of the bin above them;
    ties go to the lower bin.
    """
    rotation = np.mod(rotation_deg, 360.0)
    bins = np.floor(rotation * (HISTOGRAM_BINS / 360.0) + 0.5).astype(np.int64) % HISTOGRAM_BINS
    counts = np.bincount(bins, minlength=HISTOGRAM_BINS)
    ranked = np.argsort(-counts, kind="stable")[:3]
    kept = [int(ranked[0])]
    for previous, current in itertools.pairwise(ranked):
        if counts[current] == 0 or counts[current] < _SECONDARY_FRACTION * counts[previous]:
            break
        kept.append(int(current))
    return np.isin(bins, kept)

