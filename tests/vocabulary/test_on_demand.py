"""The shipped vocabulary loaded at its first use: nothing loaded before, the loaded one's answers after."""

from __future__ import annotations

import dataclasses

import numpy as np

from zenslam.frontend.config import FrontendConfig
from zenslam.frontend.node import load_relocalisation_vocabulary
from zenslam.vocabulary import load_vocabulary
from zenslam.vocabulary.on_demand import ShippedVocabularyOnDemand


def test_the_shipped_vocabulary_loads_at_its_first_transform_and_answers_as_the_loaded_one():
    descriptors = np.random.default_rng(3).integers(0, 256, (200, 32), dtype=np.uint8)
    on_demand = ShippedVocabularyOnDemand()
    assert not on_demand.loaded
    bow, fvec = on_demand.transform(descriptors)
    assert on_demand.loaded
    expected_bow, expected_fvec = load_vocabulary(None).transform(descriptors)
    np.testing.assert_array_equal(bow.word_ids, expected_bow.word_ids)
    np.testing.assert_array_equal(bow.weights, expected_bow.weights)
    np.testing.assert_array_equal(fvec.node_ids, expected_fvec.node_ids)
    assert len(fvec.features) == len(expected_fvec.features)
    for got, expected in zip(fvec.features, expected_fvec.features):
        np.testing.assert_array_equal(got, expected)


def test_the_frontend_holds_the_shipped_vocabulary_unloaded_and_none_without_relocalisation():
    config = FrontendConfig()
    vocabulary = load_relocalisation_vocabulary(config)
    assert isinstance(vocabulary, ShippedVocabularyOnDemand) and not vocabulary.loaded
    tracking = dataclasses.replace(config.tracking, relocalisation=dataclasses.replace(config.tracking.relocalisation, enabled=False))
    assert load_relocalisation_vocabulary(dataclasses.replace(config, tracking=tracking)) is None
