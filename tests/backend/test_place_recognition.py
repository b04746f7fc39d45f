"""Place recognition's per-keyframe vectors: the feature nodes local mapping asks for, computed once."""

from __future__ import annotations

import numpy as np

from zenslam.backend.place_recognition import PlaceRecognition
from zenslam.vocabulary import FeatureVector, load_vocabulary


class _Counting:
    """The default vocabulary, counting its ``transform`` calls."""

    def __init__(self) -> None:
        self.inner = load_vocabulary(None)
        self.transforms = 0

    def transform(self, descriptors, levels_up=None):
        self.transforms += 1
        return self.inner.transform(descriptors, levels_up)


def test_feature_nodes_are_the_feature_vectors_nodes_per_feature():
    features = FeatureVector(np.array([3, 8]), (np.array([0, 4]), np.array([2])))
    assert features.node_of_features(6).tolist() == [3, -1, 8, -1, 3, -1]
    assert FeatureVector.empty().node_of_features(2).tolist() == [-1, -1]


def test_a_keyframe_is_transformed_once_whether_local_mapping_or_indexing_asks_first():
    rng = np.random.default_rng(7)
    descriptors = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    vocabulary = _Counting()
    places = PlaceRecognition(vocabulary)
    nodes = places.feature_nodes(5, descriptors)  # the keyframe local mapping is inserting
    places.add(5, descriptors)  # indexed after local mapping: the same vectors, not transformed again
    assert vocabulary.transforms == 1
    expected = vocabulary.inner.transform(descriptors)[1]
    assert nodes.tolist() == expected.node_of_features(300).tolist()
    assert places.feature_vectors[5].node_ids.tolist() == expected.node_ids.tolist()
    assert (nodes >= 0).sum() > 250 and len(np.unique(nodes[nodes >= 0])) > 20
    places.add(6, descriptors[::-1])  # never asked for: transformed when indexed
    assert places.feature_nodes(6, descriptors[::-1]).tolist() == nodes[::-1].tolist()
    assert places.feature_nodes(5, descriptors) is nodes and vocabulary.transforms == 2
    places.remove([5])
    assert 5 not in places.feature_vectors
    places.feature_nodes(5, descriptors)
    assert vocabulary.transforms == 3  # forgotten with the keyframe


def test_vectors_restored_from_a_saved_map_replace_what_was_computed_for_the_id():
    rng = np.random.default_rng(8)
    descriptors = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    places = PlaceRecognition(load_vocabulary(None))
    places.feature_nodes(3, descriptors)
    saved = FeatureVector(np.array([11]), (np.arange(50),))
    places.restore_all([3], [places.vocabulary.transform(descriptors)[0]], [saved])
    assert places.feature_nodes(3, descriptors).tolist() == [11] * 50
