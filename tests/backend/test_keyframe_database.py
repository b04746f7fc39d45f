"""Keyframe database: inverted index, ORB-SLAM's common-word and group-accumulation rules, removal."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.backend.keyframe_database import KeyframeDatabase, KeyframeDatabaseError


@dataclass(frozen=True)
class Bow:
    word_ids: np.ndarray
    weights: np.ndarray


def bow(words: list[int]) -> Bow:
    ids = np.asarray(sorted(words), dtype=np.int64)
    return Bow(ids, np.full(len(ids), 1.0 / len(ids)))


def l1_score(a: Bow, b: Bow) -> float:
    common, ia, ib = np.intersect1d(a.word_ids, b.word_ids, return_indices=True)
    return float(np.minimum(a.weights[ia], b.weights[ib]).sum())


def graph(edges: dict[tuple[int, int], int], kfs: list[int]) -> CovisibilityGraph:
    g = CovisibilityGraph(15)
    for k in kfs:
        g.add_keyframe(k)
    for (a, b), w in edges.items():
        g.change_weight(a, b, w)
    return g


def test_common_words_count_shared_words_and_removal_forgets_them() -> None:
    db = KeyframeDatabase()
    db.add(1, bow([1, 2, 3]))
    db.add(2, bow([3, 4]))
    assert db.common_words(bow([2, 3, 9])) == {1: 2, 2: 1}
    db.remove(1)
    assert db.common_words(bow([2, 3, 9])) == {2: 1}
    assert 1 not in db and len(db) == 1
    with pytest.raises(KeyframeDatabaseError, match="keyframe 1 is not"):
        db.remove(1)
    with pytest.raises(KeyframeDatabaseError, match="already"):
        db.add(2, bow([5]))


def test_relocalisation_prefers_the_group_that_sees_the_place() -> None:
    place = list(range(100))
    db = KeyframeDatabase()
    db.add(10, bow(place[:90] + [500]))  # the place, seen by 10, 11, 12 (covisible)
    db.add(11, bow(place[3:98] + [501]))  # the best view of it
    db.add(12, bow(place[10:100] + [502]))
    db.add(20, bow(place[:88] + list(range(600, 700))))  # a lone look-alike sharing many words
    db.add(30, bow(list(range(1000, 1100))))  # elsewhere
    g = graph({(10, 11): 50, (11, 12): 50, (10, 12): 30}, [10, 11, 12, 20, 30])
    found = db.relocalisation_candidates(bow(place), g, l1_score)
    assert [c.keyframe_id for c in found] == [11]  # the group's best keyframe, once; the look-alike's lone score is too low
    assert found[0].accumulated_score > found[0].score  # the group's scores were summed


def test_loop_candidates_exclude_the_keyframes_own_neighbourhood_and_low_scores() -> None:
    place = list(range(100))
    db = KeyframeDatabase()
    db.add(1, bow(place))  # the same place, long ago
    db.add(50, bow(place[:95] + [700]))  # the query's covisible neighbour
    db.add(51, bow(place[:97] + [701]))  # the query itself
    g = graph({(50, 51): 80}, [1, 50, 51])
    found = db.loop_candidates(51, db.bow(51), 0.5, g, l1_score)
    assert [c.keyframe_id for c in found] == [1]
    assert db.loop_candidates(51, db.bow(51), 0.99, g, l1_score) == []


def test_queries_are_ordered_deterministically() -> None:
    db = KeyframeDatabase()
    for k in (5, 3, 4):
        db.add(k, bow([1, 2, 3]))
    g = graph({}, [3, 4, 5])
    assert [c.keyframe_id for c in db.relocalisation_candidates(bow([1, 2, 3]), g, l1_score)] == [3, 4, 5]
