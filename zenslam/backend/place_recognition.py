"""Place recognition's state: the vocabulary, the keyframe database and each keyframe's feature vector.

Kept in step with the map by its owner, the backend node: a keyframe's bag-of-words and feature
vectors are computed once, when local mapping first asks for its features' nodes (triangulation,
as ORB-SLAM's local mapping computes the new keyframe's bag of words first) or when it is indexed
after local mapping, and forgotten when it is culled. Loop closing and relocalisation queries both
read it.
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
        self._feature_nodes: dict[int, np.ndarray] = {}  # keyframe id -> node of each feature (``feature_nodes``)
        self._pending: tuple[int, BowVector, FeatureVector] | None = None  # vectors of a keyframe not indexed yet

    def add(self, kf_id: int, descriptors: np.ndarray) -> None:
        """Index keyframe ``kf_id`` by its (N, 32) uint8 descriptors."""
        pending, self._pending = self._pending, None
        if pending is not None and pending[0] == kf_id:
            _, bow, features = pending
        else:
            bow, features = self.vocabulary.transform(descriptors)
        self.database.add(kf_id, bow)
        self.feature_vectors[kf_id] = features

    def feature_nodes(self, kf_id: int, descriptors: np.ndarray) -> np.ndarray:
        """(N,) int64: the vocabulary node each of keyframe ``kf_id``'s (N, 32) descriptors is under at
        the feature vectors' level, -1 for a stopped word (ORB-SLAM's direct index, per feature). A
        keyframe not indexed yet (the one local mapping is inserting) is transformed here, and
        ``add`` then indexes it by that result."""
        nodes = self._feature_nodes.get(kf_id)
        if nodes is None:
            features = self.feature_vectors.get(kf_id)
            if features is None:
                bow, features = self.vocabulary.transform(descriptors)
                self._pending = (kf_id, bow, features)
            nodes = self._feature_nodes[kf_id] = features.node_of_features(len(descriptors))
        return nodes

    def restore_all(self, kf_ids: list[int], bows: list[BowVector], features: list[FeatureVector]) -> None:
        """Index keyframes ``kf_ids`` (in that order) by vectors computed earlier with this vocabulary
        (a saved map's), all at once."""
        self.database.add_all(kf_ids, bows)
        self.feature_vectors.update(zip(kf_ids, features))
        for kf_id in kf_ids:
            self._feature_nodes.pop(kf_id, None)

    def remove(self, kf_ids: list[int]) -> None:
        """Forget culled keyframes (ids not indexed are ignored)."""
        for kf_id in kf_ids:
            self._feature_nodes.pop(kf_id, None)
            if kf_id in self.database:
                self.database.remove(kf_id)
                self.feature_vectors.pop(kf_id, None)

    def bow(self, kf_id: int) -> BowVector:
        return self.database.bow(kf_id)

    def score(self, a: BowVector, b: BowVector) -> float:
        """The vocabulary's similarity of two bag-of-words vectors, in [0, 1]."""
        return self.vocabulary.score(a, b)
