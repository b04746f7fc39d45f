"""The backend map's invariants, checked from scratch (tests and debugging; not on the per-keyframe path).

The check reads the map through ``CheckedMap``, the parts of ``BackendMap`` it needs, so that this
module sits below the map, which calls it (``BackendMap.check_consistency``).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from typing import Protocol

import numpy as np

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.backend.keyframe import BackendKeyframe
from zenslam.backend.map_point import MapPoint
from zenslam.backend.spanning_tree import SpanningTree


class CheckedMap(Protocol):
    """What the consistency check reads of a backend map."""

    keyframes: Mapping[int, BackendKeyframe]
    points: Mapping[int, MapPoint]
    covisibility: CovisibilityGraph
    spanning_tree: SpanningTree
    first_keyframe_id: int | None


def consistency_problems(bmap: CheckedMap) -> list[str]:
    """Every broken invariant of ``bmap``, described (empty when the map is consistent): observations
    mirrored on both sides, weighted observation counts, covisibility weights, the graphs' nodes and
    the spanning tree reaching the first keyframe."""
    problems: list[str] = []
    for point_id, pt in bmap.points.items():
        weighted = 0
        for kf_id, keypoint in pt.observations.items():
            kf = bmap.keyframes.get(kf_id)
            if kf is None or kf.map_point_ids[keypoint] != point_id:
                problems.append(f"point {point_id} -> keyframe {kf_id} keypoint {keypoint} is not mirrored")
            else:
                weighted += 2 if kf.right_u[keypoint] >= 0 else 1
        if weighted != pt.weighted_observations:
            problems.append(f"point {point_id} weighted observations {pt.weighted_observations} != {weighted}")
    for kf_id, kf in bmap.keyframes.items():
        for keypoint in np.flatnonzero(kf.map_point_ids >= 0).tolist():
            pt = bmap.points.get(int(kf.map_point_ids[keypoint]))
            if pt is None or pt.observations.get(kf_id) != keypoint:
                problems.append(f"keyframe {kf_id} keypoint {keypoint} -> point {kf.map_point_ids[keypoint]} is not mirrored")
            elif kf.map_point_rows[keypoint] != pt.row:
                problems.append(f"keyframe {kf_id} keypoint {keypoint}: row {kf.map_point_rows[keypoint]} != point row {pt.row}")
        if np.any((kf.map_point_rows >= 0) != (kf.map_point_ids >= 0)):
            problems.append(f"keyframe {kf_id}: point rows and ids disagree on which keypoints are associated")
    shared: Counter[tuple[int, int]] = Counter()
    for pt in bmap.points.values():
        observers = sorted(pt.observations)
        shared.update((a, b) for i, a in enumerate(observers) for b in observers[i + 1 :])
    cov = bmap.covisibility
    actual = {(a, b): w for a in cov.keyframes() for b, w in cov.weights(a).items() if a < b}
    if actual != dict(shared):
        diff = set(actual.items()) ^ set(shared.items())
        problems.append(f"covisibility weights differ from the recomputed ones at {sorted(diff)[:5]}")
    problems.extend(_graph_node_problems(bmap))
    return problems


def _graph_node_problems(bmap: CheckedMap) -> list[str]:
    problems = []
    ids = sorted(bmap.keyframes)
    tree = bmap.spanning_tree
    if bmap.covisibility.keyframes() != ids or tree.keyframes() != ids:
        problems.append("the graphs' keyframes differ from the map's")
        return problems
    for kf_id in ids:
        node, steps = kf_id, 0
        while (parent := tree.parent(node)) is not None and steps <= len(ids):
            if node not in tree.children(parent):
                problems.append(f"keyframe {node} is not among the children of its parent {parent}")
            node, steps = parent, steps + 1
        if node != bmap.first_keyframe_id:
            problems.append(f"keyframe {kf_id} does not reach the first keyframe in the spanning tree")
    return problems
