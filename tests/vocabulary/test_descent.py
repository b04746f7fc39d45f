"""The compiled descent of the vocabulary tree takes every descriptor to the leaf and node numpy's
level-by-level descent took, on the shipped vocabulary and on uneven trees (leaves at several
depths, inner nodes with fewer children than the widest), at every grouping level."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.vocabulary import load_vocabulary
from zenslam.vocabulary.vocabulary import Vocabulary

from descent_numpy_reference import descend as numpy_descend  # noqa: E402  (tests/vocabulary is on the path)
from vocabulary_helpers import flip_bits, random_descriptors  # noqa: E402


def _uneven_tree(rng: np.random.Generator) -> Vocabulary:
    """A tree of depth up to 4 whose nodes have 0-5 children at random (the root at least 2)."""
    parents, frontier = [-1], [0]
    for depth in range(4):
        nxt = []
        for node in frontier:
            for _ in range(rng.integers(2 if node == 0 else 0, 6)):
                parents.append(node)
                nxt.append(len(parents) - 1)
        frontier = nxt
    n = len(parents)
    return Vocabulary(5, 4, np.array(parents), random_descriptors(rng, n), rng.uniform(0.0, 2.0, n))


@pytest.mark.parametrize("seed", range(4))
def test_uneven_trees_descend_as_numpy_did(seed) -> None:
    rng = np.random.default_rng(seed)
    vocabulary = _uneven_tree(rng)
    descriptors = np.vstack([random_descriptors(rng, 400), flip_bits(rng, vocabulary.descriptors[1:60], 3)])
    d64 = descriptors.view(np.uint64)
    for node_level in range(0, 6):
        got, expected = vocabulary._descend(d64, node_level), numpy_descend(vocabulary, d64, node_level)
        for a, b in zip(got, expected):
            np.testing.assert_array_equal(a, b)
    depths = vocabulary._node_depth[got[0]]
    assert len(np.unique(depths)) > 1  # leaves at more than one depth were reached


def test_the_shipped_vocabulary_descends_as_numpy_did() -> None:
    rng = np.random.default_rng(11)
    vocabulary = load_vocabulary(None)
    # descriptors near its nodes' (ties between children are likely) and random ones
    near = flip_bits(rng, vocabulary.descriptors[rng.integers(1, len(vocabulary.descriptors), 1500)], 2)
    d64 = np.vstack([near, random_descriptors(rng, 500)]).view(np.uint64)
    for node_level in (0, 2, 5, 7):
        got, expected = vocabulary._descend(d64, node_level), numpy_descend(vocabulary, d64, node_level)
        for a, b in zip(got, expected):
            np.testing.assert_array_equal(a, b)
