"""Search by projection, rotation consistency and brute-force matching on synthetic correspondences."""

import numpy as np
import pytest

from zenslam.descriptors import hamming_distance
from zenslam.frontend.feature_matcher import match_by_descriptor, rotation_consistent, search_by_projection


def flip_bits(desc, n_bits, rng):
    """Copy of desc (32,) uint8 with n_bits distinct bits flipped."""
    bits = np.unpackbits(desc)
    bits[rng.choice(256, n_bits, replace=False)] ^= 1
    return np.packbits(bits)


def with_distance(desc, n_bits):
    """Copy of desc with exactly its first n_bits bits flipped (distance n_bits, deterministic)."""
    bits = np.unpackbits(desc)
    bits[:n_bits] ^= 1
    return np.packbits(bits)


def make_scene(seed, n_kp=800, n_true=500, n_extra=200, max_flips=25):
    """Keypoints with random descriptors; map points 0..n_true-1 are noisy copies of known keypoints."""
    rng = np.random.default_rng(seed)
    kp_px = rng.uniform([0, 0], [1226, 370], (n_kp, 2))
    kp_level = rng.integers(0, 8, n_kp)
    kp_desc = rng.integers(0, 256, (n_kp, 32), dtype=np.uint8)
    truth = rng.permutation(n_kp)[:n_true]
    m = n_true + n_extra
    proj_px = rng.uniform([0, 0], [1226, 370], (m, 2))
    proj_px[:n_true] = kp_px[truth] + rng.normal(scale=1.5, size=(n_true, 2))
    level = rng.integers(0, 8, m)
    level[:n_true] = kp_level[truth]
    desc = rng.integers(0, 256, (m, 32), dtype=np.uint8)
    for row, t in enumerate(truth):
        desc[row] = flip_bits(kp_desc[t], int(rng.integers(0, max_flips)), rng)
    return proj_px, level, desc, kp_px, kp_level, kp_desc, truth


def single(kp_offsets, kp_levels, kp_dists, predicted_level=3, radius=10.0, **kwargs):
    """One projection at (100, 100) against keypoints at given offsets, levels and descriptor distances."""
    base = np.zeros(32, dtype=np.uint8)
    kp_px = np.array([100.0, 100.0]) + np.asarray(kp_offsets, dtype=float).reshape(-1, 2)
    kp_desc = np.array([with_distance(base, d) for d in kp_dists])
    return search_by_projection(
        np.array([[100.0, 100.0]]), np.array([predicted_level]), base[None], kp_px, np.asarray(kp_levels),
        kp_desc, radius, **kwargs,
    )[0]


@pytest.mark.parametrize("seed", [0, 1])
def test_search_by_projection_finds_the_true_keypoints(seed):
    proj_px, level, desc, kp_px, kp_level, kp_desc, truth = make_scene(seed)
    match = search_by_projection(proj_px, level, desc, kp_px, kp_level, kp_desc, 4.0 * 1.2**level * 2.0)
    assert match.dtype == np.int32 and match.shape == (len(proj_px),)
    found = match[: len(truth)]
    correct = found == truth
    assert correct.mean() > 0.95  # recall
    assert correct.sum() / max((match >= 0).sum(), 1) > 0.99  # precision over every projection
    matched = match[match >= 0]
    assert len(np.unique(matched)) == len(matched)  # one-to-one


def test_window_is_a_square_with_strict_bounds():
    assert single([[9.9, 9.9]], [3], [5]) == 0  # corner of the square, inside
    assert single([[10.0, 0.0]], [3], [5]) == -1  # on the border: ORB-SLAM uses a strict <
    assert single([[0.0, -10.1]], [3], [5]) == -1
    assert single([[0.0, -10.1]], [3], [5], radius=10.2) == 0


def test_per_projection_radius():
    proj = np.array([[100.0, 100.0], [300.0, 100.0]])
    kp_px = proj + [6.0, 0.0]
    desc = np.zeros((2, 32), dtype=np.uint8)
    match = search_by_projection(proj, [0, 0], desc, kp_px, [0, 0], desc, np.array([5.0, 7.0]))
    np.testing.assert_array_equal(match, [-1, 1])


def test_level_window_limits():
    assert single([[0, 0]], [1], [5], predicted_level=3) == -1  # below predicted - 1
    assert single([[0, 0]], [2], [5], predicted_level=3) == 0
    assert single([[0, 0]], [4], [5], predicted_level=3) == -1  # above predicted (local-map window)
    assert single([[0, 0]], [4], [5], predicted_level=3, max_level_offset=1) == 0  # motion-model window
    assert single([[0, 0]], [7], [5], predicted_level=3, max_level_offset=None) == 0
    assert single([[0, 0]], [0], [5], predicted_level=3, min_level_offset=None) == 0


def test_ratio_test_only_between_candidates_on_the_same_level():
    assert single([[0, 0], [3, 3]], [3, 3], [10, 12]) == -1  # 10 > 0.8 * 12
    assert single([[0, 0], [3, 3]], [3, 2], [10, 12]) == 0  # second best on another level
    assert single([[0, 0], [3, 3]], [3, 3], [10, 12], ratio=None) == 0
    assert single([[0, 0], [3, 3]], [3, 3], [9, 12]) == 0  # 9 <= 0.8 * 12


def test_max_distance_threshold():
    assert single([[0, 0]], [3], [100]) == 0
    assert single([[0, 0]], [3], [101]) == -1
    assert single([[0, 0]], [3], [40], max_distance=30) == -1


def test_already_matched_keypoints_are_skipped():
    assert single([[0, 0], [3, 3]], [3, 2], [5, 20], already_matched=np.array([True, False])) == 1


def test_stereo_check_on_right_coordinate():
    kwargs = {"proj_right_u": np.array([60.0])}
    assert single([[0, 0]], [3], [5], kp_right_u=np.array([65.0]), **kwargs) == 0
    assert single([[0, 0]], [3], [5], kp_right_u=np.array([75.0]), **kwargs) == -1
    assert single([[0, 0]], [3], [5], kp_right_u=np.array([-1.0]), **kwargs) == 0  # mono keypoint: no check


def test_conflicts_keep_the_nearest_descriptor_and_losers_search_again():
    base = np.zeros(32, dtype=np.uint8)
    proj = np.array([[100.0, 100.0], [102.0, 100.0]])
    desc = np.array([with_distance(base, 20), base])  # projection 1 is the closer one to keypoint 0
    kp_px = np.array([[101.0, 100.0], [96.0, 100.0]])
    kp_desc = np.array([base, with_distance(desc[0], 30)])  # 30 bits from projection 0, 10 from projection 1
    match = search_by_projection(proj, [0, 0], desc, kp_px, [0, 1], kp_desc, 5.0, ratio=None, min_level_offset=None,
                                 max_level_offset=None)
    np.testing.assert_array_equal(match, [1, 0])  # projection 0 falls back to keypoint 1
    match_once = search_by_projection(proj, [0, 0], desc, kp_px, [0, 1], kp_desc, 5.0, ratio=None,
                                      min_level_offset=None, max_level_offset=None, max_passes=1)
    np.testing.assert_array_equal(match_once, [-1, 0])


def test_equal_distances_resolve_to_lower_indices():
    desc = np.zeros((2, 32), dtype=np.uint8)
    proj = np.array([[100.0, 100.0], [101.0, 100.0]])
    kp_px = np.array([[100.5, 100.0]])
    match = search_by_projection(proj, [0, 0], desc, kp_px, [0], desc[:1], 5.0, max_passes=1)
    np.testing.assert_array_equal(match, [0, -1])
    two_kp = search_by_projection(proj[:1], [0], desc[:1], np.array([[103.0, 100.0], [97.0, 100.0]]), [0, 1],
                                  desc, 5.0)
    assert two_kp[0] == 0


def test_search_by_projection_is_deterministic_and_handles_empty_inputs():
    proj_px, level, desc, kp_px, kp_level, kp_desc, _ = make_scene(2)
    a = search_by_projection(proj_px, level, desc, kp_px, kp_level, kp_desc, 30.0, ratio=None)
    b = search_by_projection(proj_px, level, desc, kp_px, kp_level, kp_desc, 30.0, ratio=None)
    np.testing.assert_array_equal(a, b)
    empty = search_by_projection(np.zeros((0, 2)), [], np.zeros((0, 32), np.uint8), kp_px, kp_level, kp_desc, 5.0)
    assert empty.shape == (0,)
    none = search_by_projection(proj_px, level, desc, np.zeros((0, 2)), [], np.zeros((0, 32), np.uint8), 5.0)
    assert none.shape == (len(proj_px),) and (none == -1).all()


def test_projections_outside_the_image_or_non_finite_find_nothing():
    proj_px, level, desc, kp_px, kp_level, kp_desc, _ = make_scene(3, n_true=0)
    proj_px[:3] = [[-500.0, 100.0], [2000.0, 100.0], [np.nan, 5.0]]
    match = search_by_projection(proj_px[:3], level[:3], desc[:3], kp_px, kp_level, kp_desc, 20.0)
    np.testing.assert_array_equal(match, [-1, -1, -1])


def test_rotation_histogram_keeps_the_dominant_bins():
    rng = np.random.default_rng(4)
    consistent = 20.0 + rng.normal(scale=2.0, size=200)
    stray = np.array([100.0, 200.0, 300.0])
    keep = rotation_consistent(np.concatenate([consistent, stray]))
    assert keep[:200].mean() > 0.95 and not keep[200:].any()


def test_rotation_histogram_second_bin_needs_a_tenth_of_the_first():
    diffs = np.concatenate([np.full(100, 24.0), np.full(10, 120.0), np.full(9, 240.0), np.full(5, 300.0)])
    keep = rotation_consistent(diffs)
    assert keep[:110].all() and not keep[110:].any()  # 10 >= 0.1 * 100 kept; 9 < 10 dropped; 3rd bin gone
    keep = rotation_consistent(np.concatenate([np.full(100, 24.0), np.full(9, 120.0), np.full(50, 240.0)]))
    assert keep[:100].all() and not keep[100:109].any() and keep[109:].all()


def test_rotation_histogram_wraps_around_360():
    near_zero = [-1.0, 359.0, 2.0, 355.0, 721.0, 0.0, 1.0, -2.0, 358.0, 3.0, 4.0]  # all round to bin 0
    keep = rotation_consistent(np.array(near_zero + [180.0, np.nan]))
    np.testing.assert_array_equal(keep, [True] * 11 + [False, False])  # 1 < 0.1 * 11: 180 deg dropped
    assert rotation_consistent(np.array([])).shape == (0,)


def test_match_by_descriptor_recovers_correspondences_one_to_one():
    rng = np.random.default_rng(5)
    desc_b = rng.integers(0, 256, (700, 32), dtype=np.uint8)
    truth = rng.permutation(700)[:400]
    desc_a = rng.integers(0, 256, (500, 32), dtype=np.uint8)  # rows 400.. are distractors
    desc_a[:400] = [flip_bits(desc_b[t], int(rng.integers(0, 30)), rng) for t in truth]
    pairs = match_by_descriptor(desc_a, desc_b)
    assert pairs.shape[1] == 2
    assert np.all(np.diff(pairs[:, 0]) > 0)  # sorted by i, one match per row of a
    assert len(np.unique(pairs[:, 1])) == len(pairs)  # one per row of b
    correct = (pairs[:, 0] < 400) & (truth[np.minimum(pairs[:, 0], 399)] == pairs[:, 1])
    assert correct.mean() > 0.99  # precision
    assert correct.sum() / 400 > 0.95  # recall
    np.testing.assert_array_equal(pairs, match_by_descriptor(desc_a, desc_b))  # deterministic


def test_match_by_descriptor_agrees_with_brute_force_reference():
    rng = np.random.default_rng(6)
    desc_a = rng.integers(0, 256, (60, 32), dtype=np.uint8)
    desc_b = np.array([flip_bits(desc_a[i % 60], int(rng.integers(0, 60)), rng) for i in range(90)])
    dist = hamming_distance(desc_a, desc_b)
    order = np.argsort(dist, axis=1, kind="stable")
    best, second = dist[np.arange(60), order[:, 0]], dist[np.arange(60), order[:, 1]]
    accepted = {i: order[i, 0] for i in range(60) if best[i] <= 50 and best[i] < 0.7 * second[i]}
    expected = []
    for i, j in accepted.items():
        rivals = [k for k, jj in accepted.items() if jj == j]
        if min(rivals, key=lambda k: (best[k], k)) == i:
            expected.append((i, j))
    np.testing.assert_array_equal(match_by_descriptor(desc_a, desc_b), np.array(expected).reshape(-1, 2))


def test_match_by_descriptor_ratio_threshold_and_empty_inputs():
    base = np.zeros(32, dtype=np.uint8)
    desc_b = np.array([with_distance(base, 10), with_distance(base, 20)])
    assert len(match_by_descriptor(base[None], desc_b, ratio=0.5)) == 0  # 10 < 0.5 * 20 is false: strict
    np.testing.assert_array_equal(match_by_descriptor(base[None], desc_b, ratio=0.51), [[0, 0]])
    assert len(match_by_descriptor(base[None], desc_b)) == 1  # 10 < 0.7 * 20
    assert len(match_by_descriptor(base[None], desc_b, ratio=None)) == 1
    assert len(match_by_descriptor(base[None], desc_b[:1], max_distance=9)) == 0
    np.testing.assert_array_equal(match_by_descriptor(base[None], desc_b[:1]), [[0, 0]])  # no second: no ratio
    assert match_by_descriptor(np.zeros((0, 32), np.uint8), desc_b).shape == (0, 2)
    assert match_by_descriptor(base[None], np.zeros((0, 32), np.uint8)).shape == (0, 2)
