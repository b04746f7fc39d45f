"""Covisibility graph: exact weights, ORB-SLAM's threshold with the single-best fallback, ordering."""

from __future__ import annotations

import pytest

from zenslam.backend.covisibility import CovisibilityGraph


def graph_with(weights: dict[tuple[int, int], int], min_weight: int = 15) -> CovisibilityGraph:
    graph = CovisibilityGraph(min_weight)
    for kf in sorted({k for pair in weights for k in pair}):
        graph.add_keyframe(kf)
    for (a, b), w in weights.items():
        graph.change_weight(a, b, w)
    return graph


def test_weights_count_shared_observations_symmetrically() -> None:
    graph = CovisibilityGraph()
    for kf in (0, 1, 2):
        graph.add_keyframe(kf)
    graph.add_observation(1, [0])  # kf 1 sees a point kf 0 sees
    graph.add_observation(2, [0, 1])  # kf 2 sees a point both see
    assert graph.weight(0, 1) == graph.weight(1, 0) == 1
    assert graph.weight(0, 2) == graph.weight(1, 2) == 1
    graph.remove_observation(2, [0, 1])
    assert graph.weight(0, 2) == 0 and 2 not in graph.weights(0)
    with pytest.raises(ValueError, match="would become -1"):
        graph.change_weight(0, 2, -1)


def test_edges_need_the_threshold_and_are_ordered_best_first_with_id_ties() -> None:
    graph = graph_with({(0, 1): 40, (0, 2): 15, (0, 3): 14, (0, 4): 40, (1, 2): 30, (1, 3): 20})
    assert graph.connected(0) == [1, 4, 2]  # 0-3 (14) is below 15 and 3 has a strong edge of its own
    assert graph.best_covisible(0, 2) == [1, 4]
    assert graph.covisible_by_weight(0, 40) == [1, 4]


def test_keyframe_without_strong_edge_gets_its_single_best_on_both_sides() -> None:
    graph = graph_with({(0, 1): 40, (0, 3): 14, (1, 3): 9, (2, 3): 14})
    # 3 has no edge >= 15: it keeps its best, a tie between 0 and 2 broken by the smaller id ...
    assert 3 in graph.connected(0)  # ... and the fallback edge is on the other side too
    assert graph.connected(2) == [3]  # 2's own fallback edge
    assert graph.connected(3) == [0, 2]  # its own fallback, plus 2's landing on it
    assert 1 not in graph.connected(3)  # 1-3 (9) is neither strong nor anyone's best
    assert graph.edges() == [(0, 1, 40), (0, 3, 14), (2, 3, 14)]


def test_threshold_is_configurable_and_must_be_positive() -> None:
    graph = graph_with({(0, 1): 20, (0, 2): 25}, min_weight=25)
    assert graph.covisible_by_weight(0, 25) == [2]
    assert graph.connected(1) == [0]  # 1 has no edge >= 25: its best one
    assert graph.connected(0) == [2, 1]
    with pytest.raises(ValueError, match="positive"):
        CovisibilityGraph(0)


def test_removing_a_keyframe_drops_its_weights() -> None:
    graph = graph_with({(0, 1): 20, (1, 2): 25})
    graph.remove_keyframe(1)
    assert graph.keyframes() == [0, 2]
    assert graph.weights(0) == {} and graph.connected(2) == []


def test_shared_counts_and_pair_removal_equal_one_observation_at_a_time() -> None:
    batched, single = CovisibilityGraph(), CovisibilityGraph()
    for graph in (batched, single):
        for kf in (0, 1, 2, 3):
            graph.add_keyframe(kf)
    batched.add_shared(3, {0: 2, 1: 1, 2: 3})
    for others in ([0, 2], [0, 1, 2], [2]):
        single.add_observation(3, others)
    assert batched.weights(3) == single.weights(3) == {0: 2, 1: 1, 2: 3}
    batched.change_weight(0, 2, 1)
    batched.remove_shared([0, 2, 3])  # a point seen by 0, 2 and 3 leaves: -1 for each pair
    assert batched.weight(0, 3) == 1 and batched.weight(2, 3) == 2 and 2 not in batched.weights(0)
