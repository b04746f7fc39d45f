"""Place recognition's state: the vocabulary, the keyframe database and each keyframe's feature vector.

Kept in step with the map by its owner, the backend node: a keyframe's bag-of-words and feature
vectors are computed once, when local mapping has inserted it (its descriptors are here), and
forgotten when it is culled. Loop closing and relocalisation queries both read it.
"""

from __future__ import annotations

import numpy as np

from zenslam.backend.keyframe_database import KeyframeDatabase
from zenslam.vocabulary import BowVector, FeatureVector, Vocabulary


class PlaceRecognition:
    """The map's keyframes as bags of words: database (inverted index) and direct index per keyframe."""

    def __init__(self, vocabulary: Vocabulary) -> None:
        self.vocabulary = vocabulary
        self.database = KeyframeDatabase()
        self.feature_vectors: dict[int, FeatureVector] = {}

    def add(self, kf_id: int, descriptors: np.ndarray) -> None:
        """Index keyframe ``kf_id`` by its (N, 32) uint8 descriptors."""
        bow, features = self.vocabulary.transform(descriptors)
        self.database.add(kf_id, bow)
        self.feature_vectors[kf_id] = features

    def restore_all(self, kf_ids: list[int], bows: list[BowVector], features: list[FeatureVector]) -> None:
        """Index keyframes ``kf_ids`` (in that order) by vectors computed earlier with this vocabulary
        (a saved map's), all at once."""
        self.database.add_all(kf_ids, bows)
        self.feature_vectors.update(zip(kf_ids, features))

    def remove(self, kf_ids: list[int]) -> None:
        """Forget culled keyframes (ids not indexed are ignored)."""
        for kf_id in kf_ids:
            if kf_id in self.database:
                self.database.remove(kf_id)
                self.feature_vectors.pop(kf_id, None)

    def bow(self, kf_id: int) -> BowVector:
        return self.database.bow(kf_id)

    def score(self, a: BowVector, b: BowVector) -> float:
        """The vocabulary's similarity of two bag-of-words vectors, in [0, 1]."""
        return self.vocabulary.score(a, b)
