"""Loop detection: ORB-SLAM's consistency over consecutive keyframes and its guards."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.backend.keyframe_database import KeyframeDatabase
from zenslam.backend.loop_closing_config import LoopDetectionConfig
from zenslam.backend.loop_detection import LoopDetector


@dataclass(frozen=True)
class Bow:
    word_ids: np.ndarray
    weights: np.ndarray


def bow(words) -> Bow:
    ids = np.asarray(sorted(set(words)), dtype=np.int64)
    return Bow(ids, np.full(len(ids), 1.0 / len(ids)))


def l1_score(a: Bow, b: Bow) -> float:
    _, ia, ib = np.intersect1d(a.word_ids, b.word_ids, return_indices=True)
    return float(np.minimum(a.weights[ia], b.weights[ib]).sum())


def place_words(i: int) -> list[int]:
    """Keyframe i of a path sees words drifting along the path: neighbours share most words."""
    return list(range(10 * i, 10 * i + 60))


class Corridor:
    """A path of keyframes 0..n-1, each covisible with the next two, and a database of them."""

    def __init__(self) -> None:
        self.db = KeyframeDatabase()
        self.graph = CovisibilityGraph(15)
        self.detector = LoopDetector(LoopDetectionConfig(min_keyframes=5, keyframes_after_loop=5, min_consistency=3))

    def insert(self, kf: int, words: list[int]):
        self.graph.add_keyframe(kf)
        for other in (kf - 1, kf - 2):
            if other in self.graph:
                self.graph.change_weight(kf, other, 40)
        self.db.add(kf, bow(words))
        return self.detector.detect(kf, kf, self.db.bow(kf), self.db, self.graph, l1_score)


def test_a_revisit_becomes_a_loop_after_three_consistent_keyframes() -> None:
    c = Corridor()
    for i in range(30):
        assert c.insert(i, place_words(i)).consistent == ()
    # The path comes back: keyframes 30.. see the places of 2, 3, 4, ...
    found = []
    for j, i in enumerate(range(30, 36)):
        detection = c.insert(i, place_words(2 + j))
        found.append(detection.consistent)
        if j < 3:
            assert detection.consistent == (), f"keyframe {i} reported a loop before 3 consistent keyframes"
    assert any(found[3:]), "a revisit seen by 4 consecutive keyframes was never consistent"
    loop_to = [k for k in found[3:] if k][0][0]
    assert 2 <= loop_to <= 9


def test_a_single_lookalike_never_becomes_a_loop() -> None:
    c = Corridor()
    for i in range(30):
        c.insert(i, place_words(i))
    for i, words in zip(range(30, 36), [place_words(3), place_words(500), place_words(20), place_words(600), place_words(8), place_words(700)]):
        assert c.insert(i, words).consistent == ()


def test_no_detection_in_a_young_map_or_right_after_a_loop() -> None:
    c = Corridor()
    for i in range(5):
        assert c.insert(i, place_words(0)).candidates == ()
    c.detector.loop_closed(serial=5)
    assert c.insert(5, place_words(0)).candidates == ()
