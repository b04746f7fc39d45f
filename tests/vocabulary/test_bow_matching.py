"""SearchByBoW: matches within shared vocabulary nodes, ratio and distance tests, one-to-one, rotation consistency."""

from __future__ import annotations

import numpy as np
from vocabulary_helpers import flip_bits, full_tree, random_descriptors

from zenslam.vocabulary import FeatureVector
from zenslam.vocabulary.bow_matching import rotation_consistent, search_by_bow


def one_node(n: int) -> FeatureVector:
    return FeatureVector(np.array([7]), (np.arange(n),))


def with_distance(rng: np.random.Generator, base: np.ndarray, bits: int) -> np.ndarray:
    return flip_bits(rng, base[None], bits)[0]


def test_true_matches_are_found_through_the_vocabulary():
    """Image b sees 150 of image a's 200 features (shuffled, 8 bits of noise, rotated by 30 degrees)."""
    rng = np.random.default_rng(40)
    vocabulary = full_tree(rng, 10, 3)
    # features 40 bits from the level-1 nodes (random strings are ~128 apart): 8 bits of noise keep them there
    desc_a = flip_bits(rng, vocabulary.descriptors[rng.integers(1, 11, 200)], 40)
    angles_a = rng.uniform(0, 360, 200)
    seen = rng.permutation(200)[:150]
    desc_b = np.concatenate([flip_bits(rng, desc_a[seen], 8), random_descriptors(rng, 50)])
    angles_b = np.concatenate([np.mod(angles_a[seen] - 30 + rng.normal(0, 2, 150), 360), rng.uniform(0, 360, 50)])
    _, fvec_a = vocabulary.transform(desc_a, levels_up=2)
    _, fvec_b = vocabulary.transform(desc_b, levels_up=2)
    idx_a, idx_b = search_by_bow(fvec_a, desc_a, angles_a, fvec_b, desc_b, angles_b)
    assert idx_a.dtype == np.int64 and idx_b.dtype == np.int64
    assert np.all(np.diff(idx_a) > 0) and len(set(idx_b.tolist())) == len(idx_b)
    truth = dict(zip(seen.tolist(), range(150)))
    correct = sum(truth.get(a) == b for a, b in zip(idx_a.tolist(), idx_b.tolist()))
    assert correct == len(idx_a)  # no wrong match
    assert correct >= 145


def test_distance_threshold_is_strict_and_ratio_test_rejects_ambiguity():
    rng = np.random.default_rng(41)
    a = random_descriptors(rng, 3)
    b = np.stack([
        with_distance(rng, a[0], 50),  # a0: at TH_LOW exactly: no match
        with_distance(rng, a[1], 49),  # a1: below it: match
        with_distance(rng, a[2], 10),  # a2: 10 bits away ...
        with_distance(rng, a[2], 12),  # ... and a second candidate 12 away: 10 >= 0.75 * 12: rejected
    ])
    angles = np.zeros(4)
    idx_a, idx_b = search_by_bow(one_node(3), a, angles[:3], one_node(4), b, angles)
    assert idx_a.tolist() == [1] and idx_b.tolist() == [1]


def test_only_shared_nodes_are_compared_and_usable_masks_hold():
    rng = np.random.default_rng(42)
    a = random_descriptors(rng, 4)
    b = flip_bits(rng, a, 3)
    angles = np.zeros(4)
    fvec_a = FeatureVector(np.array([1, 2]), (np.array([0, 1]), np.array([2, 3])))
    fvec_b = FeatureVector(np.array([2, 5]), (np.array([2, 3]), np.array([0, 1])))  # 0, 1 under another node
    idx_a, idx_b = search_by_bow(fvec_a, a, angles, fvec_b, b, angles)
    assert idx_a.tolist() == [2, 3] and idx_b.tolist() == [2, 3]
    usable_a = np.array([True, True, False, True])
    usable_b = np.array([True, True, True, False])
    idx_a, _ = search_by_bow(fvec_a, a, angles, fvec_b, b, angles, usable_a=usable_a, usable_b=usable_b)
    assert idx_a.size == 0


def test_one_to_one_the_earlier_feature_takes_the_match():
    rng = np.random.default_rng(43)
    target = random_descriptors(rng, 1)
    a = np.stack([with_distance(rng, target[0], 5), with_distance(rng, target[0], 3)])
    angles = np.zeros(2)
    idx_a, idx_b = search_by_bow(one_node(2), a, angles, one_node(1), target, angles[:1])
    assert idx_a.tolist() == [0] and idx_b.tolist() == [0]  # feature 1 is nearer but comes later, as in ORB-SLAM


def test_matches_with_an_inconsistent_rotation_are_dropped():
    rng = np.random.default_rng(44)
    a = random_descriptors(rng, 40)
    b = flip_bits(rng, a, 4)
    angles_a = rng.uniform(0, 360, 40)
    angles_b = np.mod(angles_a - 90, 360)
    angles_b[:4] = np.mod(angles_a[:4] + 150, 360)  # four matches rotated otherwise
    idx_a, _ = search_by_bow(one_node(40), a, angles_a, one_node(40), b, angles_b)
    assert idx_a.tolist() == list(range(4, 40))
    idx_a, _ = search_by_bow(one_node(40), a, angles_a, one_node(40), b, angles_b, check_orientation=False)
    assert idx_a.tolist() == list(range(40))


def test_rotation_histogram_keeps_three_peaks_each_a_tenth_of_the_one_above():
    rotations = np.concatenate([np.full(50, 12.0), np.full(20, 100.0), np.full(5, 200.0), np.full(3, 300.0)])
    kept = rotation_consistent(rotations)
    assert kept[:75].all() and not kept[75:].any()  # 300 degrees is the fourth peak
    kept = rotation_consistent(np.concatenate([np.full(100, 5.0), np.full(9, 100.0), np.full(8, 200.0)]))
    assert kept[:100].all() and not kept[100:].any()  # 9 < 0.1 * 100: no second peak, hence no third
    # bins of 12 degrees centred on multiples of 12, wrapping at 360: 40 in the bin of 0, one (6.1) in the next
    kept = rotation_consistent(np.append(np.tile([359.0, -1.0, 0.0, 5.9], 10), 6.1))
    assert kept[:40].all() and not kept[40]
