"""Essential graph: spanning tree + covisibility >= 100 + loop edges, each pair once, sorted."""

from __future__ import annotations

import pytest

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.backend.essential_graph import EssentialEdge, EssentialGraph
from zenslam.backend.spanning_tree import SpanningTree


def build() -> EssentialGraph:
    graph = CovisibilityGraph(15)
    tree = SpanningTree()
    for kf, parent in ((0, None), (1, 0), (2, 1), (3, 2), (4, 3)):
        graph.add_keyframe(kf)
        tree.add(kf, parent)
    for (a, b), w in {(0, 1): 150, (1, 2): 120, (0, 2): 100, (2, 3): 99, (3, 4): 30, (1, 3): 101}.items():
        graph.change_weight(a, b, w)
    return EssentialGraph(tree, graph, min_weight=100)


def test_edge_set_and_kinds() -> None:
    essential = build()
    essential.add_loop_edge(4, 0)
    essential.add_loop_edge(1, 0)  # already a tree edge: listed once, as spanning_tree
    assert essential.edges() == [
        EssentialEdge(0, 1, "spanning_tree"),
        EssentialEdge(0, 2, "covisibility"),  # weight 100 is enough
        EssentialEdge(0, 4, "loop"),
        EssentialEdge(1, 2, "spanning_tree"),
        EssentialEdge(1, 3, "covisibility"),
        EssentialEdge(2, 3, "spanning_tree"),  # 99 shared: only as the tree edge
        EssentialEdge(3, 4, "spanning_tree"),
    ]
    assert essential.loop_edges() == [(0, 1), (0, 4)]


def test_loop_edges_validation_and_removal() -> None:
    essential = build()
    with pytest.raises(ValueError, match="two different"):
        essential.add_loop_edge(2, 2)
    with pytest.raises(ValueError, match="not in the map"):
        essential.add_loop_edge(2, 9)
    essential.add_loop_edge(4, 0)
    assert essential.has_loop_edge(4) and not essential.has_loop_edge(3)
    essential.remove_keyframe(4)
    assert essential.loop_edges() == []
