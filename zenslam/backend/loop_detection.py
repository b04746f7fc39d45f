"""Loop detection as ORB-SLAM2's ``LoopClosing::DetectLoop``: database candidates kept only when consistent.

For each new keyframe the minimum score against its covisible neighbours sets the bar a loop
candidate must reach (a place as similar as the keyframe's own surroundings). Each candidate's
group (itself and its covisible keyframes) is compared with the groups that were candidates for
the previous keyframes: sharing a keyframe with one extends that group's consistency by one. A
candidate becomes a loop to verify once its consistency reaches ``min_consistency`` (3 consecutive
keyframes by default), so a single lucky match never triggers a loop. Nothing is detected while
the map is young or shortly after a loop was closed.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.backend.keyframe_database import BagOfWords, Candidate, KeyframeDatabase
from zenslam.backend.loop_closing_config import LoopDetectionConfig

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ConsistentGroup:
    """Keyframe ids of a candidate's covisibility group and for how many keyframes it has recurred."""

    keyframes: frozenset[int]
    consistency: int


@dataclass(frozen=True)
class Detection:
    """What one keyframe's detection found: database candidates, and those consistent enough to verify."""

    keyframe_id: int
    min_score: float  # lowest score of the keyframe against its covisible neighbours
    candidates: tuple[Candidate, ...]
    consistent: tuple[int, ...]  # candidate keyframe ids to verify, best first


class LoopDetector:
    """ORB-SLAM's candidate consistency over consecutive keyframes; holds the previous groups."""

    def __init__(self, config: LoopDetectionConfig) -> None:
        self.config = config
        self.groups: list[ConsistentGroup] = []
        self.last_loop_serial = -(10**9)  # insertion serial of the keyframe of the last closed loop

    def detect(
        self,
        kf_id: int,
        serial: int,
        bow: BagOfWords,
        database: KeyframeDatabase,
        covisibility: CovisibilityGraph,
        score: Callable[[BagOfWords, BagOfWords], float],
    ) -> Detection:
        """Candidates for keyframe ``kf_id`` (insertion ``serial``), already in ``database``, and the
        consistent ones."""
        cfg = self.config
        if len(database) <= cfg.min_keyframes or serial - self.last_loop_serial < cfg.keyframes_after_loop:
            return Detection(kf_id, 0.0, (), ())
        neighbours = covisibility.connected(kf_id) if kf_id in covisibility else []
        scores = [score(bow, database.bow(k)) for k in neighbours if k in database]
        min_score = min(scores) if scores else 0.0
        candidates = database.loop_candidates(kf_id, bow, min_score, covisibility, score)
        if not candidates:
            self.groups = []
            return Detection(kf_id, min_score, (), ())
        consistent = self._update_groups(candidates, covisibility)
        return Detection(kf_id, min_score, tuple(candidates), tuple(consistent))

    def loop_closed(self, serial: int) -> None:
        """A loop was closed at the keyframe of insertion ``serial``: wait before detecting again."""
        self.last_loop_serial = serial
        self.groups = []

    def _update_groups(self, candidates: list[Candidate], covisibility: CovisibilityGraph) -> list[int]:
        """Carry the consistency of previous groups to the candidates' groups; the candidates reaching
        ``min_consistency``."""
        current: list[ConsistentGroup] = []
        extended = [False] * len(self.groups)
        enough: list[int] = []
        for candidate in candidates:
            k = candidate.keyframe_id
            members = frozenset(covisibility.connected(k) if k in covisibility else []) | {k}
            consistent_with_any = False
            added_enough = False
            for i, previous in enumerate(self.groups):
                if members.isdisjoint(previous.keyframes):
                    continue
                consistent_with_any = True
                consistency = previous.consistency + 1
                if not extended[i]:
                    current.append(ConsistentGroup(members, consistency))
                    extended[i] = True
                if consistency >= self.config.min_consistency and not added_enough:
                    enough.append(k)
                    added_enough = True
            if not consistent_with_any:
                current.append(ConsistentGroup(members, 0))
        self.groups = current
        return enough
