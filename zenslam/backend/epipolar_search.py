"""Triangulation's candidate pairs under one vocabulary node, compiled (``SearchForTriangulation``).

``triangulation.candidate_pairs`` states the rules: a pair of keypoints without a map point, one of
each keyframe, under the same vocabulary node, whose second keypoint lies inside the epipolar band
of the first, whose descriptors differ by at most the distance threshold, and which, when neither
has stereo, is not next to the epipole. This kernel applies them one pair at a time instead of
numpy's arrays of every pair under a node. The band test takes the caller's line coefficients and
gates and makes the products numpy's formulation makes, in its order (no fastmath), so the pairs
are the same on any x86-64 CPU; distances are integers.
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel
from zenslam.descriptor_words import distance


@kernel
def node_pair_candidates(
    lines, line_norm2, first, count, order2, uv2, gate2, idx1, words1, idx2, words2, max_distance, mono1, mono2,
    epipole, epipole_gate2,
):  # fmt: skip
    """(i1, i2, distance) of the candidate pairs, by their first keypoint's row then their second's.

    Row r of the first keyframe's keypoints (``idx1[r]``, epipolar line ``lines[r]`` = (a, b, c) in
    the second image, ``line_norm2[r]`` = a^2 + b^2) is paired with the second keyframe's rows
    ``order2[first[r]:first[r] + count[r]]`` (those under its node, ascending). Row c of the second
    (``idx2[c]`` at ``uv2[c]``) is in the band when (a u + b v + c)^2 < ``gate2[c]`` x a^2 + b^2
    (``gate2``: chi2 x its level's sigma^2). ``mono1`` / ``mono2``: rows without stereo; a pair of
    two such rows is dropped when its second keypoint is near the ``epipole`` (u, v) in the second
    image: its squared distance below ``epipole_gate2[c]`` (empty: the first keyframe is not in
    front of the second, no epipole).
    """
    total = 0
    for r in range(len(first)):
        total += count[r]
    out1 = np.empty(total, np.int64)
    out2 = np.empty(total, np.int64)
    out_distance = np.empty(total, np.int64)
    n = 0
    for r in range(len(first)):
        a, b, offset = lines[r, 0], lines[r, 1], lines[r, 2]
        norm2 = line_norm2[r]
        for k in range(first[r], first[r] + count[r]):
            c = order2[k]
            signed = a * uv2[c, 0] + b * uv2[c, 1] + offset
            if not signed * signed < gate2[c] * norm2:
                continue
            d = distance(words1, idx1[r], words2, idx2[c])
            if d > max_distance:
                continue
            if mono1[r] and mono2[c] and len(epipole_gate2):
                du, dv = uv2[c, 0] - epipole[0], uv2[c, 1] - epipole[1]
                if du * du + dv * dv < epipole_gate2[c]:
                    continue
            out1[n], out2[n], out_distance[n] = idx1[r], idx2[c], d
            n += 1
    return out1[:n], out2[:n], out_distance[:n]
