"""Training a vocabulary tree: DBoW2's structure, determinism, idf weights."""

from __future__ import annotations

import math

import numpy as np
import pytest
from vocabulary_helpers import clustered_descriptors, random_descriptors

from zenslam.errors import ConfigError, VocabularyError
from zenslam.vocabulary.training import TrainingConfig, train_vocabulary


@pytest.fixture(scope="module")
def images() -> list[np.ndarray]:
    rng = np.random.default_rng(10)
    centres = random_descriptors(rng, 60)
    out = []
    for _ in range(40):
        chosen = rng.choice(60, size=20, replace=False)
        d, _ = clustered_descriptors(rng, centres[chosen], per_centre=5, n_bits=12)
        out.append(d)
    return out


def test_tree_has_dbow2_structure(images):
    vocabulary = train_vocabulary(images, TrainingConfig(branching=4, depth=3))
    parents = vocabulary.parents
    assert parents[0] == -1 and np.all(parents[1:] < np.arange(1, vocabulary.n_nodes))
    assert np.bincount(parents[1:]).max() <= 4
    assert vocabulary.node_depth.max() <= 3
    assert 1 < vocabulary.n_words <= 4**3
    assert np.all(np.diff(vocabulary.node_depth) >= 0)  # numbered level by level
    assert vocabulary.weights[~vocabulary.is_leaf].sum() == 0


def test_same_descriptors_and_seed_give_the_same_vocabulary_and_another_seed_another(images):
    config = TrainingConfig(branching=5, depth=3, seed=3)
    a, b = train_vocabulary(images, config), train_vocabulary(images, config)
    for name in ("parents", "descriptors", "weights"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    c = train_vocabulary(images, TrainingConfig(branching=5, depth=3, seed=4))
    assert not np.array_equal(a.descriptors, c.descriptors[: a.n_nodes]) or a.n_nodes != c.n_nodes


def test_at_most_k_distinct_descriptors_become_leaves_and_duplicates_one_word():
    rng = np.random.default_rng(11)
    distinct = random_descriptors(rng, 3)
    images = [distinct[[0, 1, 1]], distinct[[2, 2]], distinct[[0]]]
    vocabulary = train_vocabulary(images, TrainingConfig(branching=4, depth=2))
    assert vocabulary.n_nodes == 4 and vocabulary.n_words == 3
    assert {bytes(d) for d in vocabulary.descriptors[1:]} == {bytes(d) for d in distinct}


def test_idf_is_log_of_images_over_images_with_the_word():
    rng = np.random.default_rng(12)
    a, b, c = random_descriptors(rng, 3)
    # word a in all 4 images (stopped), b in 2, c in 1
    images = [np.stack([a, b]), np.stack([a, b, b]), np.stack([a]), np.stack([a, c])]
    vocabulary = train_vocabulary(images, TrainingConfig(branching=4, depth=1))
    idf = dict(zip((bytes(d) for d in vocabulary.descriptors[1:]), vocabulary.weights[1:]))
    assert idf[bytes(a)] == 0.0
    assert idf[bytes(b)] == pytest.approx(math.log(4 / 2))
    assert idf[bytes(c)] == pytest.approx(math.log(4 / 1))


def test_training_descriptors_fall_into_words_near_them(images):
    vocabulary = train_vocabulary(images, TrainingConfig(branching=6, depth=3))
    descriptors = np.concatenate(images)
    words = vocabulary.words(descriptors)
    leaf = vocabulary.descriptors[vocabulary.word_node(words)]
    distance = np.unpackbits(leaf ^ descriptors, axis=1).sum(axis=1)
    assert np.median(distance) < 20  # the clusters have 12 bits of noise; random strings are 128 apart


def test_bad_training_input_and_settings_fail_clearly():
    with pytest.raises(VocabularyError, match="cannot train a vocabulary from 1 descriptors"):
        train_vocabulary([np.zeros((1, 32), np.uint8)])
    with pytest.raises(VocabularyError, match=r"expected \(N, 32\) uint8"):
        train_vocabulary([np.zeros((5, 64), np.float32)])
    with pytest.raises(ConfigError, match="branching=1"):
        TrainingConfig(branching=1)
    with pytest.raises(ConfigError, match="depth=11"):
        TrainingConfig(depth=11)
