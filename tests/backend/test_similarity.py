"""Horn's alignment, the similarity RANSAC and its refinement recover known transforms between two keyframes."""

import numpy as np
import pytest

from zenslam.backend.similarity import (
    SimilarityError,
    SimilarityMatches,
    SimilarityOptimizationConfig,
    SimilarityRansacConfig,
    find_similarity,
    horn_alignment,
    optimize_similarity,
)
from zenslam.camera import PinholeCalibration
from zenslam.geometry import invert_T, make_T, so3_exp, so3_log, transform_points

CAM = PinholeCalibration(460.0, 460.0, 320.0, 240.0, 640, 480, baseline_m=0.1)
CAM2 = PinholeCalibration(500.0, 505.0, 310.0, 250.0, 640, 480)


def two_keyframes(seed, n=200, scale=1.0, outlier_fraction=0.0, noise_px=0.5, point_noise_m=0.01):
    """Keyframe 1 and 2 seeing the same points 2-8 m ahead; keyframe 2's map is ``scale`` times smaller
    (p1 = scale R p2 + t). Returns the matches, the true (T_12, scale) and the true inlier mask."""
    rng = np.random.default_rng(seed)
    T_w1 = make_T(so3_exp([0.02, 0.1, -0.01]), [0.3, -0.1, 0.2])
    T_w2 = make_T(so3_exp([-0.05, 0.35, 0.04]), [1.1, 0.05, -0.4])
    z = rng.uniform(2.0, 8.0, n)
    uv = np.column_stack([rng.uniform(60, 580, n), rng.uniform(60, 420, n)])
    p1_true = np.column_stack([(uv[:, 0] - CAM.cx) * z / CAM.fx, (uv[:, 1] - CAM.cy) * z / CAM.fy, z])
    p_world = transform_points(T_w1, p1_true)
    p2_metric = transform_points(invert_T(T_w2), p_world)
    keep = p2_metric[:, 2] > 0.5
    p1_true, p2_metric = p1_true[keep], p2_metric[keep]
    n = len(p1_true)
    levels = rng.integers(0, 4, (2, n))
    sigma2 = 1.2 ** (2 * levels)
    px1 = project(CAM, p1_true) + rng.normal(scale=noise_px, size=(n, 2)) * np.sqrt(sigma2[0])[:, None]
    px2 = project(CAM2, p2_metric) + rng.normal(scale=noise_px, size=(n, 2)) * np.sqrt(sigma2[1])[:, None]
    depth_noise = lambda p: p * (1.0 + point_noise_m * rng.normal(size=(len(p), 1)) / p[:, 2:3])  # noisy depth
    p1, p2 = depth_noise(p1_true), depth_noise(p2_metric) / scale
    outlier = np.zeros(n, dtype=bool)
    outlier[rng.permutation(n)[: int(round(outlier_fraction * n))]] = True
    swap = rng.permutation(np.flatnonzero(outlier))  # wrong associations: another point's map point and keypoint
    p2[outlier], px2[outlier] = p2[swap], px2[swap]
    outlier &= np.linalg.norm(p2 - p2_metric / scale, axis=1) > 0.3  # a swap with a near neighbour is no outlier
    T_12 = invert_T(T_w1) @ T_w2
    matches = SimilarityMatches(p1, p2, px1, px2, sigma2[0], sigma2[1], CAM, CAM2)
    return matches, T_12, scale, ~outlier


def project(c, p):
    return np.column_stack([c.fx * p[:, 0] / p[:, 2] + c.cx, c.fy * p[:, 1] / p[:, 2] + c.cy])


def pose_error(T_a, T_b):
    """Rotation (deg) and translation (m) between two transforms."""
    d = invert_T(T_a) @ T_b
    return np.degrees(np.linalg.norm(so3_log(d[:3, :3]))), np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])


@pytest.mark.parametrize("with_scale", [False, True])
def test_horn_recovers_exact_transform(with_scale):
    rng = np.random.default_rng(1)
    p2 = rng.normal(size=(10, 3)) * 3.0
    R, t, s = so3_exp([0.4, -1.2, 2.5]), np.array([1.0, -2.0, 0.5]), (0.37 if with_scale else 1.0)
    p1 = s * p2 @ R.T + t
    T, s_est = horn_alignment(p1, p2, with_scale)
    assert s_est == pytest.approx(s, rel=1e-12)
    assert np.allclose(T[:3, :3], R, atol=1e-12) and np.allclose(T[:3, 3], t, atol=1e-11)
    assert np.allclose(T[3], [0, 0, 0, 1])


def test_horn_without_scale_keeps_unit_scale_on_scaled_data():
    rng = np.random.default_rng(2)
    p2 = rng.normal(size=(20, 3))
    R = so3_exp([0.1, 0.2, 0.3])
    T, s = horn_alignment(2.0 * p2 @ R.T, p2, with_scale=False)
    assert s == 1.0
    assert np.allclose(T[:3, :3], R, atol=1e-12)  # the rotation does not depend on the scale


def test_horn_rejects_too_few_points():
    with pytest.raises(SimilarityError, match="at least 3"):
        horn_alignment(np.zeros((2, 3)), np.zeros((2, 3)), True)


@pytest.mark.parametrize("with_scale,scale", [(False, 1.0), (True, 0.6)])
def test_ransac_finds_transform_and_inliers_with_half_outliers(with_scale, scale):
    matches, T_true, s_true, truth = two_keyframes(3, n=200, scale=scale, outlier_fraction=0.5)
    est = find_similarity(matches, with_scale, SimilarityRansacConfig(), np.random.default_rng(0))
    assert est is not None
    rot_deg, trans_m = pose_error(est.T_12, T_true)
    assert rot_deg < 0.5 and trans_m < 0.05
    assert est.scale == pytest.approx(s_true, rel=0.02)
    # every true outlier rejected, almost every true inlier found
    assert not (est.inliers & ~truth).any()
    assert est.inliers[truth].mean() > 0.9
    assert est.iterations <= SimilarityRansacConfig().max_iterations


def test_ransac_is_deterministic_for_a_seed():
    matches, *_ = two_keyframes(4, outlier_fraction=0.5)
    a = find_similarity(matches, True, SimilarityRansacConfig(), np.random.default_rng(7))
    b = find_similarity(matches, True, SimilarityRansacConfig(), np.random.default_rng(7))
    assert np.array_equal(a.T_12, b.T_12) and a.scale == b.scale and np.array_equal(a.inliers, b.inliers)


def test_ransac_returns_none_without_consensus():
    matches, *_ = two_keyframes(5, n=60, outlier_fraction=1.0)
    assert find_similarity(matches, False, SimilarityRansacConfig(), np.random.default_rng(0)) is None
    few, *_ = two_keyframes(5, n=60)
    assert find_similarity(few, False, SimilarityRansacConfig(min_inliers=100), np.random.default_rng(0)) is None


@pytest.mark.parametrize("with_scale,scale", [(False, 1.0), (True, 1.7)])
def test_optimize_refines_a_perturbed_transform_and_drops_outliers(with_scale, scale):
    matches, T_true, s_true, truth = two_keyframes(6, n=150, scale=scale, outlier_fraction=0.3, point_noise_m=0.0)
    start = T_true @ make_T(so3_exp([0.02, -0.01, 0.015]), [0.05, -0.03, 0.04])
    est = optimize_similarity(matches, start, s_true * 1.05 if with_scale else 1.0, with_scale, SimilarityOptimizationConfig())
    assert est is not None
    rot_deg, trans_m = pose_error(est.T_12, T_true)
    assert rot_deg < 0.05 and trans_m < 0.01
    assert est.scale == pytest.approx(s_true, rel=2e-3)
    assert not (est.inliers & ~truth).any() and est.inliers[truth].mean() > 0.95
    assert est.n_inliers == int(est.inliers.sum())


def test_optimize_returns_none_when_too_few_matches_survive():
    matches, T_true, *_ = two_keyframes(8, n=30, outlier_fraction=0.9)
    assert optimize_similarity(matches, T_true, 1.0, False, SimilarityOptimizationConfig(min_inliers=10)) is None


def test_matches_are_validated():
    with pytest.raises(SimilarityError, match="px2 has shape"):
        SimilarityMatches(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 2)), np.zeros((2, 2)), np.ones(3), np.ones(3), CAM, CAM)


def test_refinement_jacobian_matches_finite_differences():
    from zenslam.backend import similarity

    matches, T, s, _ = two_keyframes(9, n=20, scale=1.3)
    R, t = T[:3, :3] @ so3_exp([0.01, 0.02, 0.0]), T[:3, 3] + 0.1
    rows = np.arange(len(matches))
    J, *_ = similarity._linearize(matches, rows, R, t, s, huber=1e9)
    numeric = np.zeros_like(J)
    for k in range(7):
        step = np.zeros(7)
        step[k] = 1e-6
        plus = np.concatenate([r.ravel() for r in similarity._residuals(matches, rows, *similarity._retract(R, t, s, step))[:2]])
        minus = np.concatenate([r.ravel() for r in similarity._residuals(matches, rows, *similarity._retract(R, t, s, -step))[:2]])
        numeric[:, k] = (plus - minus) / 2e-6
    assert np.abs(J - numeric).max() < 1e-5 * np.abs(J).max()
