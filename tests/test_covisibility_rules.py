"""Covisibility rules shared by both stages: ranking, ordered connections, the fallback edge, parent choice."""

from __future__ import annotations

from zenslam.covisibility_rules import fallback_connection, ordered_connections, ranked, spanning_parent, strongest


def test_ranking_is_strongest_first_with_ties_to_the_smaller_key() -> None:
    weights = {7: 20, 3: 20, 9: 40, 1: 5}
    assert ranked(weights) == [9, 3, 7, 1]
    assert ranked(weights, [1, 7, 3]) == [3, 7, 1]
    assert strongest(weights) == 9 and strongest(weights, [1, 7, 3]) == 3
    assert strongest({}) is None and ranked({}) == []


def test_ordered_connections_keep_the_strong_pairs_or_the_single_strongest() -> None:
    assert ordered_connections({4: 15, 2: 30, 5: 14}, 15) == [2, 4]
    assert ordered_connections({4: 3, 2: 9, 5: 9}, 15) == [2]  # none reaches 15: the strongest alone
    assert ordered_connections({}, 15) == []


def test_the_fallback_connection_exists_only_without_a_strong_pair() -> None:
    assert fallback_connection({4: 3, 2: 9, 5: 9}, 15) == 2
    assert fallback_connection({4: 3, 2: 15}, 15) is None
    assert fallback_connection({}, 15) is None


def test_the_parent_is_the_candidate_sharing_most_points() -> None:
    weights = {0: 12, 1: 30, 2: 30, 5: 40}
    assert spanning_parent(weights) == 5
    assert spanning_parent(weights, [0, 1, 2]) == 1  # tie between 1 and 2: the smaller key
    assert spanning_parent(weights, [3, 4]) is None  # shares no point with any candidate
    assert spanning_parent({}) is None
