"""Spanning tree: parent = most shared points at insertion, ORB-SLAM's re-parenting on removal."""

from __future__ import annotations

import pytest

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.backend.spanning_tree import SpanningTree, choose_parent


def covisibility(weights: dict[tuple[int, int], int], kfs: range) -> CovisibilityGraph:
    graph = CovisibilityGraph(15)
    for kf in kfs:
        graph.add_keyframe(kf)
    for (a, b), w in weights.items():
        graph.change_weight(a, b, w)
    return graph


def test_parent_is_the_older_keyframe_sharing_most_points() -> None:
    graph = covisibility({(3, 0): 20, (3, 1): 50, (3, 2): 50}, range(4))
    assert choose_parent(3, graph, [0, 1, 2]) == 1  # tie 1/2 at 50 goes to the smaller id
    assert choose_parent(3, graph, [0]) == 0
    assert choose_parent(0, graph, []) is None
    lonely = covisibility({}, range(3))
    assert choose_parent(2, lonely, [0, 1]) == 1  # no shared point: the most recent keyframe


def test_tree_bookkeeping_and_cycle_guard() -> None:
    tree = SpanningTree()
    tree.add(0, None)
    tree.add(1, 0)
    tree.add(2, 1)
    assert tree.children(0) == [1] and tree.parent(2) == 1
    assert tree.edges() == [(1, 0), (2, 1)]
    with pytest.raises(ValueError, match="cycle"):
        tree.set_parent(1, 2)
    with pytest.raises(ValueError, match="root"):
        tree.add(3, None)
    tree.set_parent(2, 0)
    assert tree.children(0) == [1, 2] and tree.children(1) == []


def test_removal_reattaches_children_to_the_best_candidate_as_orb_slam() -> None:
    # 0 <- 1 <- {2, 3, 4, 5}; remove 1.
    weights = {(1, 2): 60, (1, 3): 60, (1, 4): 60, (1, 5): 60, (2, 0): 40, (3, 2): 50, (3, 0): 10, (4, 0): 20}
    graph = covisibility(weights, range(6))
    tree = SpanningTree()
    tree.add(0, None)
    tree.add(1, 0)
    for child in (2, 3, 4, 5):
        tree.add(child, 1)
    for child in (2, 3, 4, 5):
        graph.change_weight(1, child, -60)  # the removed keyframe's observations leave the graph first
    graph.remove_keyframe(1)
    moves = tree.remove(1, graph)
    # round 1: candidates {0}: 2-0 (40) beats 4-0 (20) (3-0 is 10, below the threshold: not connected)
    # round 2: candidates {0, 2}: 3-2 (50); round 3: 4-0 (20); 5 has no connection: original parent 0
    assert moves == {2: 0, 3: 2, 4: 0, 5: 0}
    assert tree.parent(3) == 2 and tree.children(0) == [2, 4, 5]
    assert 1 not in tree


def test_the_root_cannot_be_removed() -> None:
    tree = SpanningTree()
    tree.add(0, None)
    with pytest.raises(ValueError, match="root"):
        tree.remove(0, covisibility({}, range(1)))
