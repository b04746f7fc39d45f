"""Map points' representative descriptors, compiled (ORB-SLAM's ``ComputeDistinctiveDescriptors``).

``map_point_rules.representative_descriptor`` states the rule: of a point's observations, the
descriptor with the least median Hamming distance to the others (the median of a row of K sorted
distances, itself included at 0, is element (K - 1) // 2), the first on a tie. This kernel takes
the observations as runs (point p's are ``starts[p]:starts[p] + counts[p]``) instead of padded
groups; every step is an integer one, the same on any CPU.
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel
from zenslam.descriptor_words import distance


@kernel
def representative_offsets(words, starts, counts):
    """(P,) int64: the offset within its run of each point's representative observation.

    ``words`` (O, 4) uint64: the observations' descriptors; ``starts``, ``counts`` (P,) their runs."""
    n = len(starts)
    out = np.zeros(n, np.int64)
    widest = 0
    for p in range(n):
        widest = max(widest, counts[p])
    distances = np.empty((widest, widest), np.int64)
    row = np.empty(widest, np.int64)
    for p in range(n):
        k, first = counts[p], starts[p]
        if k <= 2:
            continue  # one or two: every median is 0 (the distance to itself), the first wins
        for i in range(k):
            distances[i, i] = 0
            for j in range(i + 1, k):
                distances[i, j] = distances[j, i] = distance(words, first + i, words, first + j)
        best, best_median = 0, np.int64(0)
        for i in range(k):
            for j in range(k):
                row[j] = distances[i, j]
            median = np.sort(row[:k])[(k - 1) // 2]
            if i == 0 or median < best_median:
                best, best_median = i, median
        out[p] = best
    return out
