"""Hamming distances agree with a bit-by-bit count."""

import numpy as np

from zenslam.descriptors import hamming_distance, hamming_distance_pairs


def test_hamming_matches_unpackbits_reference():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, size=(7, 32), dtype=np.uint8)
    b = rng.integers(0, 256, size=(5, 32), dtype=np.uint8)
    reference = np.unpackbits(a[:, None, :] ^ b[None, :, :], axis=2).sum(axis=2)
    np.testing.assert_array_equal(hamming_distance(a, b), reference)
    np.testing.assert_array_equal(hamming_distance_pairs(a[:5], b), np.diag(reference[:5]))


def test_identical_and_complementary_descriptors():
    d = np.zeros((1, 32), dtype=np.uint8)
    assert hamming_distance(d, d)[0, 0] == 0
    assert hamming_distance(d, ~d)[0, 0] == 256
