"""k-majority clustering of many groups at once: centres are bitwise majorities, labels the nearest centres."""

from __future__ import annotations

import numpy as np
from vocabulary_helpers import clustered_descriptors, random_descriptors

from zenslam.descriptors import hamming_distance
from zenslam.vocabulary.k_majority import _update_centres, k_majority


def naive_majority(descriptors: np.ndarray) -> np.ndarray:
    bits = np.unpackbits(descriptors, axis=1).astype(np.int64)
    return np.packbits(2 * bits.sum(axis=0) >= descriptors.shape[0])


def test_centres_are_bitwise_majorities_also_past_255_members():
    rng = np.random.default_rng(1)
    descriptors = random_descriptors(rng, 1500)
    labels = np.concatenate([np.zeros(700, int), np.full(3, 4), np.full(797, 2)])  # 700 > 255: lanes widened
    rng.shuffle(labels)
    centres = np.zeros((5, 4), dtype=np.uint64)
    _update_centres(descriptors, np.arange(1500), labels, centres)
    got = centres.view(np.uint8).reshape(5, 32)
    for label in (0, 2, 4):
        assert np.array_equal(got[label], naive_majority(descriptors[labels == label]))
    assert not got[1].any() and not got[3].any()  # no members: left as they were


def test_majority_of_an_even_tie_sets_the_bit_as_dbow2():
    descriptors = np.zeros((2, 32), np.uint8)
    descriptors[0, 0] = 0b1000_0001
    centres = np.zeros((1, 4), np.uint64)
    _update_centres(descriptors, np.arange(2), np.zeros(2, int), centres)
    assert centres.view(np.uint8)[0, 0] == 0b1000_0001


def test_separated_clusters_of_several_groups_are_recovered():
    rng = np.random.default_rng(2)
    groups, truths = [], []
    for _ in range(3):  # three groups, each of 4 well separated centres (random strings are ~128 bits apart)
        d, truth = clustered_descriptors(rng, random_descriptors(rng, 4), per_centre=40, n_bits=10)
        groups.append(d)
        truths.append(truth)
    starts = np.array([0, 160, 320, 480])
    result = k_majority(np.concatenate(groups), starts, k=4, rng=np.random.default_rng(0), max_iterations=30)
    assert result.present.all()
    for g, truth in enumerate(truths):
        labels = result.labels[starts[g] : starts[g + 1]]
        # one label per true cluster and one true cluster per label
        pairs = set(zip(truth.tolist(), labels.tolist()))
        assert len(pairs) == 4 and len({p[0] for p in pairs}) == 4 and len({p[1] for p in pairs}) == 4


def test_labels_are_the_first_nearest_centre_of_their_group():
    rng = np.random.default_rng(3)
    descriptors = random_descriptors(rng, 900)
    starts = np.array([0, 300, 305, 900])
    result = k_majority(descriptors, starts, k=5, rng=np.random.default_rng(7), max_iterations=3)
    for g in range(3):
        members = descriptors[starts[g] : starts[g + 1]]
        slots = np.flatnonzero(result.present[g])
        distance = hamming_distance(members, result.centres[g, slots])
        assert np.array_equal(slots[np.argmin(distance, axis=1)], result.labels[starts[g] : starts[g + 1]])


def test_same_seed_same_clusters_and_fewer_distinct_points_than_k_stop_the_seeding():
    rng = np.random.default_rng(4)
    distinct = random_descriptors(rng, 3)
    descriptors = distinct[rng.integers(0, 3, 50)]  # 50 descriptors, 3 distinct
    a = k_majority(descriptors, np.array([0, 50]), k=10, rng=np.random.default_rng(5), max_iterations=30)
    b = k_majority(descriptors, np.array([0, 50]), k=10, rng=np.random.default_rng(5), max_iterations=30)
    assert np.array_equal(a.labels, b.labels) and np.array_equal(a.centres, b.centres)
    assert a.present.sum() == 3
    found = {bytes(c) for c in a.centres[0][a.present[0]]}
    assert found == {bytes(c) for c in distinct}
