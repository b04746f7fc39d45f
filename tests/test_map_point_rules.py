"""Shared map point rules: representative descriptor, viewing direction, scale-invariance range, scale prediction."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.descriptors import hamming_distance
from zenslam.map_point_rules import (
    mean_viewing_direction,
    mean_viewing_directions,
    mean_viewing_directions_of_runs,
    predict_scale_level,
    radius_by_viewing_cos,
    representative_descriptor,
    representative_descriptors,
    representative_offsets,
    scale_invariance_range,
)


def _flip_bits(desc: np.ndarray, bits: np.ndarray) -> np.ndarray:
    out = desc.copy()
    for b in bits:
        out[b // 8] ^= np.uint8(1 << (b % 8))
    return out


def test_representative_descriptor_is_the_one_with_least_median_distance() -> None:
    rng = np.random.default_rng(0)
    centre = rng.integers(0, 256, 32, dtype=np.uint8)
    # Four noisy copies of a centre and one outlier: the best is a copy, never the outlier.
    copies = [_flip_bits(centre, rng.choice(256, 6, replace=False)) for _ in range(4)]
    outlier = rng.integers(0, 256, 32, dtype=np.uint8)
    descs = np.stack([outlier, *copies])
    best = representative_descriptor(descs)
    d = hamming_distance(descs, descs)
    medians = np.sort(d, axis=1)[:, (len(descs) - 1) // 2]
    assert np.array_equal(best, descs[int(np.argmin(medians))])
    assert not np.array_equal(best, outlier)


def test_representative_descriptor_of_one_or_two() -> None:
    rng = np.random.default_rng(1)
    descs = rng.integers(0, 256, (2, 32), dtype=np.uint8)
    assert np.array_equal(representative_descriptor(descs[:1]), descs[0])
    # With two, both medians (lower median) are 0: the first wins, as in ORB-SLAM.
    assert np.array_equal(representative_descriptor(descs), descs[0])


def test_batched_representatives_match_one_by_one() -> None:
    rng = np.random.default_rng(2)
    groups = rng.integers(0, 256, (7, 5, 32), dtype=np.uint8)
    batched = representative_descriptors(groups)
    for g, b in zip(groups, batched):
        assert np.array_equal(representative_descriptor(g), b)


def test_representatives_with_ties_and_padding_are_the_brute_force_choice() -> None:
    # Descriptors drawn from 3 bases with 0-2 bits flipped: many equal medians, where the first wins.
    rng = np.random.default_rng(4)
    bases = rng.integers(0, 256, (3, 32), dtype=np.uint8)
    groups = bases[rng.integers(0, 3, (300, 12))]
    for g in groups[::3]:
        g[rng.integers(0, 12)] = _flip_bits(g[0], rng.choice(256, rng.integers(0, 3), replace=False))
    counts = rng.integers(1, 13, 300)
    chosen = representative_descriptors(groups, counts)
    ties = 0
    for g, k, c in zip(groups, counts, chosen):
        medians = np.sort(hamming_distance(g[:k], g[:k]), axis=1)[:, (k - 1) // 2]
        assert np.array_equal(c, g[int(np.argmin(medians))])
        ties += int(np.count_nonzero(medians == medians.min()) > 1)
    assert ties > 100
    runs = representative_offsets(groups.reshape(-1, 32), np.arange(300) * 12, counts)
    assert np.array_equal(groups[np.arange(300), runs], chosen)


def _numpy_mean_viewing_directions(p_world, centres_world, counts):
    """The padded numpy formulation the compiled one replaced (padding adds -0.0)."""
    rays = p_world[:, None, :] - centres_world
    rays /= np.maximum(np.linalg.norm(rays, axis=2, keepdims=True), 1e-12)
    rays[np.arange(rays.shape[1]) >= counts[:, None]] = -0.0
    return rays.sum(axis=1) / counts[:, None]


def test_viewing_directions_have_the_bits_of_the_numpy_formulation() -> None:
    rng = np.random.default_rng(6)
    p_world = rng.normal(0, 10, (400, 3))
    centres = rng.normal(0, 10, (400, 9, 3))
    centres[::7, 0] = p_world[::7]  # a camera centre on the point: a zero ray, kept at length 1e-12
    counts = rng.integers(1, 10, 400)
    got = mean_viewing_directions(p_world, centres, counts)
    assert got.tobytes() == _numpy_mean_viewing_directions(p_world, centres, counts).tobytes()
    full = mean_viewing_directions(p_world, centres)
    assert full.tobytes() == _numpy_mean_viewing_directions(p_world, centres, np.full(400, 9)).tobytes()
    runs = mean_viewing_directions_of_runs(p_world, centres.reshape(-1, 3), np.arange(400) * 9, counts)
    assert runs.tobytes() == got.tobytes()


def test_scale_invariance_range_follows_level() -> None:
    lo, hi = scale_invariance_range(np.array([10.0, 10.0]), np.array([0, 3]), 1.2, 8)
    assert hi[0] == pytest.approx(10.0)
    assert lo[0] == pytest.approx(10.0 / 1.2**7)
    assert hi[1] == pytest.approx(10.0 * 1.2**3)
    assert lo[1] == pytest.approx(10.0 / 1.2**4)


def test_predict_scale_inverts_the_range() -> None:
    _, hi = scale_invariance_range(5.0, 2, 1.2, 8)
    # Seen from the distance where it was created, the point is predicted on its own level.
    assert int(predict_scale_level(5.0, hi, 1.2, 8)) == 2
    # Twice as far: 1.2**3.8 ~ 2 -> about 4 levels finer, clamped at 0.
    assert int(predict_scale_level(10.0, hi, 1.2, 8)) == 0
    # Much closer: clamped at the top level.
    assert int(predict_scale_level(0.1, hi, 1.2, 8)) == 7
    levels = predict_scale_level(np.array([5.0, 5.0 / 1.2, 5.0 / 1.2**2]), hi, 1.2, 8)
    assert levels.tolist() == [2, 3, 4]


def test_mean_viewing_direction() -> None:
    p = np.array([0.0, 0.0, 10.0])
    centres = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    n = mean_viewing_direction(p, centres)
    assert n[0] == pytest.approx(0.0, abs=1e-12)
    assert n[2] == pytest.approx(10.0 / np.sqrt(101.0))


def test_radius_by_viewing_cos() -> None:
    assert radius_by_viewing_cos(np.array([0.999, 0.99])).tolist() == [2.5, 4.0]


def test_batched_viewing_directions_match_one_by_one() -> None:
    rng = np.random.default_rng(5)
    p_world = rng.normal(size=(6, 3)) * 5.0
    centres = rng.normal(size=(6, 4, 3))
    batched = mean_viewing_directions(p_world, centres)
    for k in range(6):
        np.testing.assert_array_equal(batched[k], mean_viewing_direction(p_world[k], centres[k]))


def test_padded_representatives_match_each_group_alone() -> None:
    rng = np.random.default_rng(3)
    counts = np.array([1, 2, 3, 5, 8, 8, 4, 7])
    groups = rng.integers(0, 256, (len(counts), 8, 32), dtype=np.uint8)
    groups[2, 1] = groups[2, 0]  # a tie
    padded = representative_descriptors(groups, counts)
    for g, k, b in zip(groups, counts, padded):
        assert np.array_equal(representative_descriptor(g[:k]), b)


def test_padded_viewing_directions_have_the_bits_of_each_point_alone() -> None:
    rng = np.random.default_rng(4)
    counts = np.array([1, 2, 3, 9, 16, 5])
    p = rng.normal(size=(len(counts), 3)) * 10
    centres = rng.normal(size=(len(counts), 16, 3))
    p[1], centres[1, :2] = [-0.0, 1.0, 1.0], [[0.0, 0.0, 0.0], [0.0, 2.0, 3.0]]  # a sum of -0.0 stays -0.0
    padded = mean_viewing_directions(p, centres, counts)
    for k in range(len(counts)):
        alone = mean_viewing_directions(p[k : k + 1], centres[k : k + 1, : counts[k]])[0]
        assert padded[k].tobytes() == alone.tobytes()


def test_frustum_verdict_applies_each_visibility_rule() -> None:
    from zenslam.camera import PinholeCalibration
    from zenslam.map_point_rules import frustum_verdict

    cal = PinholeCalibration(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
    p_world = np.array([[0.0, 0, 5], [0, 0, 5], [0, 0, 5], [0, 0, 5], [0, 0, 5], [0, 0, 5]])
    depth = np.array([5.0, -5.0, 5.0, 5.0, 5.0, 5.0])  # the second is behind the camera
    px = np.array([[320.0, 240], [320, 240], [640, 240], [320, 240], [320, 240], [320, 240]])  # the third off the image
    normals = np.array([[0, 0, 1.0], [0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 1], [1, 0, 0.2]])  # the last seen from the side
    min_d = np.array([1.0, 1, 1, 6.3, 1, 1])  # 5 m < 0.8 x 6.3 m: too close
    max_d = np.array([10.0, 10, 10, 10, 4.1, 10])  # 5 m > 1.2 x 4.1 m: too far
    verdict = frustum_verdict(p_world, np.zeros(3), depth, px, normals, min_d, max_d, cal, 1.2, 8)
    assert verdict.visible.tolist() == [True, False, False, False, False, False]
    assert verdict.distance_m.tolist() == [5.0] * 6
    assert verdict.view_cos[0] == 1.0 and verdict.view_cos[5] < 0.5
    assert verdict.level.tolist() == predict_scale_level(np.full(6, 5.0), max_d, 1.2, 8).tolist()
