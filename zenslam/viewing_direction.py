"""Map points' mean viewing directions, compiled (ORB-SLAM's ``UpdateNormalAndDepth``).

``map_point_rules.mean_viewing_direction`` states the rule: the mean of the unit rays from the
observing camera centres to the point, not renormalised. This kernel takes each point's centres as
a run (point p's are ``starts[p]:starts[p] + counts[p]``) instead of padded groups, and makes
numpy's operations in numpy's order: each ray's squared norm summed x, y then z, its length kept
at least 1e-12, the rays summed in the order of the run from the first, the sum divided by the
count. No fastmath: the same bits on any x86-64 CPU.
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel


@kernel
def mean_rays(p_world, centres, starts, counts):
    """(P, 3): the mean unit ray from ``centres`` (O, 3) of each point's run to ``p_world`` (P, 3)."""
    n = len(starts)
    out = np.empty((n, 3))
    ray = np.empty(3)
    total = np.empty(3)
    for p in range(n):
        for k in range(counts[p]):
            c = starts[p] + k
            for j in range(3):
                ray[j] = p_world[p, j] - centres[c, j]
            length = np.sqrt(ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2])
            if not (length >= 1e-12 or np.isnan(length)):
                length = 1e-12
            for j in range(3):
                if k == 0:
                    total[j] = ray[j] / length
                else:
                    total[j] += ray[j] / length
        for j in range(3):
            out[p, j] = total[j] / counts[p]
    return out
