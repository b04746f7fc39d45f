"""The essential graph: spanning tree, strong covisibility edges and loop edges (pose-graph edges).

ORB-SLAM's ``OptimizeEssentialGraph`` uses exactly these: every spanning-tree edge, every loop
edge, and every covisibility pair sharing at least 100 points that is not already a tree or loop
edge. Loop edges are added by loop closing; keyframes holding one are never culled.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.backend.spanning_tree import SpanningTree

EdgeKind = Literal["spanning_tree", "loop", "covisibility"]


class EssentialEdge(NamedTuple):
    """One edge of the essential graph between keyframes a < b."""

    a: int
    b: int
    kind: EdgeKind


class EssentialGraph:
    """Loop edges plus the edge listing over a spanning tree and a covisibility graph."""

    def __init__(self, spanning_tree: SpanningTree, covisibility: CovisibilityGraph, min_weight: int = 100) -> None:
        self.spanning_tree = spanning_tree
        self.covisibility = covisibility
        self.min_weight = int(min_weight)  # shared points for a covisibility edge (ORB-SLAM: 100)
        self._loops: set[tuple[int, int]] = set()

    def add_loop_edge(self, a: int, b: int) -> None:
        """Record a closed loop between keyframes ``a`` and ``b`` (both must be in the tree)."""
        if a == b:
            raise ValueError(f"a loop edge needs two different keyframes, got {a} twice")
        for kf in (a, b):
            if kf not in self.spanning_tree:
                raise ValueError(f"keyframe {kf} of loop edge ({a}, {b}) is not in the map")
        self._loops.add((min(a, b), max(a, b)))

    def loop_edges(self) -> list[tuple[int, int]]:
        """Loop edges as (a, b) with a < b, sorted."""
        return sorted(self._loops)

    def has_loop_edge(self, kf_id: int) -> bool:
        """Whether ``kf_id`` is an end of a loop edge (such keyframes are never culled)."""
        return any(kf_id in edge for edge in self._loops)

    def remove_keyframe(self, kf_id: int) -> None:
        """Forget the loop edges of a removed keyframe."""
        self._loops = {edge for edge in self._loops if kf_id not in edge}

    def edges(self) -> list[EssentialEdge]:
        """Every edge once, sorted by (a, b); a pair that is several kinds is listed as the first of
        spanning_tree, loop, covisibility."""
        kinds: dict[tuple[int, int], EdgeKind] = {}
        for child, parent in self.spanning_tree.edges():
            kinds[(min(child, parent), max(child, parent))] = "spanning_tree"
        for pair in self._loops:
            kinds.setdefault(pair, "loop")
        for a in self.covisibility.keyframes():
            for b in self.covisibility.covisible_by_weight(a, self.min_weight):
                if a < b:
                    kinds.setdefault((a, b), "covisibility")
        return [EssentialEdge(a, b, kind) for (a, b), kind in sorted(kinds.items())]
