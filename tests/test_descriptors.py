"""Hamming distances agree with a bit-by-bit count."""

import numpy as np

from zenslam.descriptors import hamming_distance, hamming_distance_pairs, hamming_distance_rows


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


def test_distances_of_rows_match_distances_of_gathered_rows():
    rng = np.random.default_rng(1)
    a = rng.integers(0, 256, size=(9, 32), dtype=np.uint8)
    b = rng.integers(0, 256, size=(6, 32), dtype=np.uint8)
    rows_a, rows_b = rng.integers(0, 9, 40), rng.integers(0, 6, 40)
    np.testing.assert_array_equal(hamming_distance_rows(a, rows_a, b, rows_b), hamming_distance_pairs(a[rows_a], b[rows_b]))
