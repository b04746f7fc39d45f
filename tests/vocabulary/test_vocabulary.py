"""Transform (words, TF-IDF BowVector, direct index) and the L1 score, against one-descriptor-at-a-time references."""

from __future__ import annotations

import numpy as np
import pytest
from vocabulary_helpers import descend_one, flip_bits, full_tree, random_descriptors

from zenslam.errors import VocabularyError
from zenslam.vocabulary import BowVector, Vocabulary


@pytest.fixture(scope="module")
def tree() -> Vocabulary:
    return full_tree(np.random.default_rng(20), k=4, depth=3)


def test_words_follow_the_nearest_child_down_the_tree(tree):
    descriptors = random_descriptors(np.random.default_rng(21), 200)
    words = tree.words(descriptors)
    for descriptor, word in zip(descriptors, words):
        assert tree.word_node(word) == descend_one(tree, descriptor)[-1]


def test_ties_go_to_the_first_child_as_in_dbow2():
    parents = np.array([-1, 0, 0])
    descriptors = np.zeros((3, 32), np.uint8)
    descriptors[1, 0] = 0b0000_0011  # both children 2 bits from the query
    descriptors[2, 1] = 0b0000_0011
    vocabulary = Vocabulary(2, 1, parents, descriptors, np.ones(3))
    assert vocabulary.words(np.zeros((1, 32), np.uint8))[0] == 0


def test_bow_vector_is_tf_idf_l1_normalised(tree):
    rng = np.random.default_rng(22)
    descriptors = random_descriptors(rng, 300)
    bow, _ = tree.transform(descriptors)
    words = tree.words(descriptors)
    expected = np.zeros(tree.n_words)
    np.add.at(expected, words, tree.word_weights[words])
    expected /= expected.sum()
    assert np.all(np.diff(bow.word_ids) > 0)
    assert np.array_equal(bow.word_ids, np.flatnonzero(expected))
    assert np.allclose(bow.weights, expected[bow.word_ids], rtol=0, atol=1e-12)
    assert bow.weights.sum() == pytest.approx(1.0)


def test_feature_vector_groups_features_by_their_node_at_the_chosen_level(tree):
    descriptors = random_descriptors(np.random.default_rng(23), 150)
    for levels_up, level in ((None, 2), (1, 2), (2, 1), (0, 3), (5, 0)):
        _, fvec = tree.transform(descriptors, levels_up=levels_up)
        assert np.all(np.diff(fvec.node_ids) > 0)
        assert np.array_equal(np.sort(np.concatenate(fvec.features)), np.arange(150))
        for node, features in zip(fvec.node_ids, fvec.features):
            assert np.all(np.diff(features) > 0)
            for i in features:
                path = [0, *descend_one(tree, descriptors[i])]
                assert path[level] == node


def test_stopped_words_are_left_out_of_both_vectors():
    rng = np.random.default_rng(24)
    weights = np.ones(1 + 4 + 16)
    weights[5:9] = 0.0  # the 4 words under node 1 are stopped
    vocabulary = full_tree(rng, 4, 2, weights)
    descriptors = random_descriptors(rng, 200)
    stopped = np.isin(vocabulary.word_node(vocabulary.words(descriptors)), [5, 6, 7, 8])
    bow, fvec = vocabulary.transform(descriptors, levels_up=1)
    assert stopped.any()
    assert not np.isin(vocabulary.word_node(bow.word_ids), [5, 6, 7, 8]).any()
    assert np.array_equal(np.sort(np.concatenate(fvec.features)), np.flatnonzero(~stopped))
    assert 1 not in fvec.node_ids


def test_a_word_shallower_than_the_direct_index_level_groups_its_features_itself():
    parents = np.array([-1, 0, 0, 2, 2])  # node 1 is a word at depth 1; nodes 3, 4 at depth 2
    descriptors = np.zeros((5, 32), np.uint8)
    descriptors[2, :] = 0xFF
    descriptors[3, :] = 0x0F
    descriptors[4, :] = 0xFF
    vocabulary = Vocabulary(2, 2, parents, descriptors, np.ones(5))
    queries = np.stack([descriptors[1], descriptors[4]])
    _, fvec = vocabulary.transform(queries, levels_up=0)
    assert fvec.node_ids.tolist() == [1, 4]


def test_score_is_one_minus_half_the_l1_distance(tree):
    rng = np.random.default_rng(25)
    a = random_descriptors(rng, 300)
    bow_a, _ = tree.transform(a)
    bow_b, _ = tree.transform(flip_bits(rng, a, 20))
    dense_a, dense_b = np.zeros(tree.n_words), np.zeros(tree.n_words)
    dense_a[bow_a.word_ids], dense_b[bow_b.word_ids] = bow_a.weights, bow_b.weights
    assert tree.score(bow_a, bow_b) == pytest.approx(1 - 0.5 * np.abs(dense_a - dense_b).sum(), abs=1e-12)
    assert tree.score(bow_a, bow_a) == pytest.approx(1.0)
    assert tree.score(bow_a, BowVector(np.array([10**9]), np.array([1.0]))) == 0.0
    assert 0.0 < tree.score(bow_a, bow_b) < 1.0


def test_empty_input_gives_empty_vectors_and_wrong_descriptors_fail(tree):
    bow, fvec = tree.transform(np.zeros((0, 32), np.uint8))
    assert len(bow) == 0 and len(fvec) == 0
    with pytest.raises(VocabularyError, match=r"\(N, 32\) uint8"):
        tree.transform(np.zeros((10, 64), np.float32))
    with pytest.raises(VocabularyError, match=r"\(N, 32\) uint8"):
        tree.transform(np.zeros((10, 16), np.uint8))


def test_a_corrupt_tree_is_refused():
    with pytest.raises(VocabularyError, match="node 2 has parent 3"):
        Vocabulary(2, 2, np.array([-1, 0, 3, 0]), np.zeros((4, 32), np.uint8), np.ones(4))
    with pytest.raises(VocabularyError, match="at least one word"):
        Vocabulary(2, 2, np.array([-1]), np.zeros((1, 32), np.uint8), np.ones(1))
