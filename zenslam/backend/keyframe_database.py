"""The keyframe database: an inverted index from vocabulary words to the keyframes holding them.

ORB-SLAM's ``KeyFrameDatabase``: each keyframe's bag-of-words vector is computed once, where its
descriptors are (the backend, at insertion), and its words are indexed; a query counts the words
each keyframe shares with the query, scores only the keyframes sharing more than 80% of the best
count, then accumulates the scores over covisibility groups so that a place seen by several
connected keyframes beats one lucky keyframe. Loop candidates exclude the query keyframe's own
covisible neighbourhood and must reach a minimum score; relocalisation candidates have neither rule.
Every list is ordered (score descending, keyframe id ascending), so queries are deterministic.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from itertools import chain, repeat
from typing import TYPE_CHECKING, Protocol

import numpy as np

from zenslam.errors import ZenslamError

if TYPE_CHECKING:
    from zenslam.backend.covisibility import CovisibilityGraph


class BagOfWords(Protocol):
    """What the database reads of a bag-of-words vector (``zenslam.vocabulary.BowVector``)."""

    word_ids: np.ndarray  # (W,) int64 ascending
    weights: np.ndarray  # (W,) float64


Score = Callable[[BagOfWords, BagOfWords], float]

MIN_COMMON_WORDS_RATIO = 0.8  # ORB-SLAM: a candidate shares more than 80% of the best count of common words
MIN_ACCUMULATED_RATIO = 0.75  # ORB-SLAM: a group is kept above 75% of the best accumulated score
GROUP_SIZE = 10  # ORB-SLAM: a candidate's group is itself and its 10 best covisible keyframes


class KeyframeDatabaseError(ZenslamError):
    """A keyframe is added twice, or removed or read while not in the database."""


@dataclass(frozen=True)
class Candidate:
    """A place found by a query: the best keyframe of a covisibility group and the group's score."""

    keyframe_id: int
    accumulated_score: float  # the group's summed score
    score: float  # the keyframe's own score


class KeyframeDatabase:
    """Bag-of-words vectors of the map's keyframes and the inverted index over their words."""

    def __init__(self) -> None:
        self._bows: dict[int, BagOfWords] = {}
        self._index: dict[int, list[int]] = {}  # word id -> keyframe ids holding it, in insertion order

    def __len__(self) -> int:
        return len(self._bows)

    def __contains__(self, kf_id: object) -> bool:
        return kf_id in self._bows

    def add(self, kf_id: int, bow: BagOfWords) -> None:
        """Index keyframe ``kf_id`` under each of its words."""
        if kf_id in self._bows:
            raise KeyframeDatabaseError(f"keyframe {kf_id} is already in the keyframe database")
        self._bows[kf_id] = bow
        index = self._index
        for word in np.asarray(bow.word_ids, dtype=np.int64).tolist():
            holders = index.get(word)
            if holders is None:
                index[word] = [kf_id]
            else:
                holders.append(kf_id)

    def add_all(self, kf_ids: list[int], bows: list[BagOfWords]) -> None:
        """``add`` each keyframe in order, the index built at once (a saved map's thousands of keyframes)."""
        known = [k for k in kf_ids if k in self._bows]
        if known or len(set(kf_ids)) != len(kf_ids):
            raise KeyframeDatabaseError(f"keyframes {sorted(set(known))[:5]} are already in the keyframe database, or listed twice")
        self._bows.update(zip(kf_ids, bows))
        words = [np.asarray(b.word_ids, dtype=np.int64) for b in bows]
        if not words:
            return
        all_words = np.concatenate(words)
        holders = np.repeat(np.asarray(kf_ids, dtype=np.int64), [len(w) for w in words])
        order = np.argsort(all_words, kind="stable")  # stable: each word's holders stay in insertion order
        distinct, starts = np.unique(all_words[order], return_index=True)
        grouped = holders[order].tolist()
        bounds = [*starts.tolist(), len(grouped)]
        for word, a, b in zip(distinct.tolist(), bounds[:-1], bounds[1:]):
            self._index.setdefault(word, []).extend(grouped[a:b])

    def remove(self, kf_id: int) -> None:
        """Forget a culled keyframe."""
        bow = self._bows.pop(kf_id, None)
        if bow is None:
            raise KeyframeDatabaseError(f"keyframe {kf_id} is not in the keyframe database")
        for word in np.asarray(bow.word_ids, dtype=np.int64).tolist():
            holders = self._index[word]
            holders.remove(kf_id)
            if not holders:
                del self._index[word]

    def bow(self, kf_id: int) -> BagOfWords:
        """The bag-of-words vector stored for ``kf_id``."""
        try:
            return self._bows[kf_id]
        except KeyError:
            raise KeyframeDatabaseError(f"keyframe {kf_id} is not in the keyframe database") from None

    def common_words(self, bow: BagOfWords, exclude: Iterable[int] = ()) -> Counter[int]:
        """Keyframe id -> number of words it shares with ``bow``, for every keyframe sharing one
        and not in ``exclude``."""
        words = np.asarray(bow.word_ids, dtype=np.int64).tolist()
        counts = Counter(chain.from_iterable(map(self._index.get, words, repeat(()))))  # C-level: ~1,000 words
        for kf_id in exclude:
            counts.pop(kf_id, None)
        return counts

    def loop_candidates(
        self, kf_id: int, bow: BagOfWords, min_score: float, covisibility: CovisibilityGraph, score: Score
    ) -> list[Candidate]:
        """ORB-SLAM's ``DetectLoopCandidates`` for keyframe ``kf_id``: keyframes outside its covisible
        neighbourhood scoring at least ``min_score``, grouped by covisibility; best first."""
        exclude = set(covisibility.connected(kf_id)) | {kf_id} if kf_id in covisibility else {kf_id}
        return self._candidates(bow, self.common_words(bow, exclude), min_score, covisibility, score)

    def relocalisation_candidates(self, bow: BagOfWords, covisibility: CovisibilityGraph, score: Score) -> list[Candidate]:
        """ORB-SLAM's ``DetectRelocalizationCandidates`` for a frame's ``bow``: every keyframe may be
        one; best first."""
        return self._candidates(bow, self.common_words(bow), 0.0, covisibility, score)

    def _candidates(
        self, bow: BagOfWords, common: Counter[int], min_score: float, covisibility: CovisibilityGraph, score: Score
    ) -> list[Candidate]:
        if not common:
            return []
        min_common = MIN_COMMON_WORDS_RATIO * max(common.values())
        scores = {k: score(bow, self._bows[k]) for k in sorted(common) if common[k] > min_common}
        matched = [k for k in scores if scores[k] >= min_score]
        groups: list[Candidate] = []
        for k in matched:
            best, best_score, accumulated = k, scores[k], scores[k]
            for neighbour in covisibility.best_covisible(k, GROUP_SIZE) if k in covisibility else ():
                if neighbour not in scores:  # scored means: shares enough words with the query
                    continue
                accumulated += scores[neighbour]
                if scores[neighbour] > best_score:
                    best, best_score = neighbour, scores[neighbour]
            groups.append(Candidate(best, accumulated, best_score))
        if not groups:
            return []
        keep = MIN_ACCUMULATED_RATIO * max(g.accumulated_score for g in groups)
        groups.sort(key=lambda g: (-g.accumulated_score, -g.score, g.keyframe_id))
        chosen: list[Candidate] = []
        seen: set[int] = set()
        for group in groups:
            if group.accumulated_score > keep and group.keyframe_id not in seen:
                seen.add(group.keyframe_id)
                chosen.append(group)
        return chosen
