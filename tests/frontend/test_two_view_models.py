"""The RANSAC pieces of two-view initialisation on exact synthetic correspondences: sample sets,
the linear H and F fits, ORB-SLAM's scores, and the Sampson refinement of a motion."""

from __future__ import annotations

import math

import numpy as np

from zenslam.frontend.two_view_models import (
    CHI2_1DOF,
    CHI2_2DOF,
    adjugate,
    draw_sample_sets,
    find_fundamental,
    find_homography,
    fit_fundamentals,
    fit_homographies,
    normalize_points,
    score_fundamentals,
    score_homographies,
)
from zenslam.frontend.two_view_refinement import refine_motion
from zenslam.geometry import skew, so3_exp, so3_log

K = np.array([[450.0, 0.0, 320.0], [0.0, 450.0, 240.0], [0.0, 0.0, 1.0]])
R_TRUE = so3_exp(np.array([0.01, -0.04, 0.02]))
T_TRUE = np.array([0.3, 0.02, 0.05])


def _project(p: np.ndarray) -> np.ndarray:
    return p[:, :2] / p[:, 2:] * 450.0 + np.array([320.0, 240.0])


def _general(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    p = np.column_stack([rng.uniform(-2.0, 2.0, (n, 2)), rng.uniform(3.0, 8.0, n)])
    return _project(p), _project(p @ R_TRUE.T + T_TRUE)


def _planar(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-2.0, 2.0, (n, 2))
    p = np.column_stack([xy, 5.0 + 0.3 * xy[:, 0] + 0.2 * xy[:, 1]])
    return _project(p), _project(p @ R_TRUE.T + T_TRUE)


def _true_F() -> np.ndarray:
    K_inv = np.linalg.inv(K)
    return K_inv.T @ skew(T_TRUE) @ R_TRUE @ K_inv


def test_sample_sets_hold_distinct_indices_and_depend_only_on_the_seed() -> None:
    sets = draw_sample_sets(20, 500, np.random.default_rng(3))
    assert sets.shape == (500, 8)
    assert sets.min() >= 0 and sets.max() < 20
    assert all(len(set(row)) == 8 for row in sets.tolist())
    # Every index is drawn about equally often (Floyd's algorithm is uniform): 200 each on average.
    counts = np.bincount(sets.ravel(), minlength=20)
    assert counts.min() > 140 and counts.max() < 260
    assert np.array_equal(sets, draw_sample_sets(20, 500, np.random.default_rng(3)))
    assert not np.array_equal(sets, draw_sample_sets(20, 500, np.random.default_rng(4)))


def test_normalised_points_are_centred_with_unit_mean_deviation() -> None:
    x, _ = _general(50)
    xn, T = normalize_points(x)
    assert np.allclose(xn.mean(axis=0), 0.0, atol=1e-12)
    assert np.allclose(np.abs(xn).mean(axis=0), 1.0)
    assert np.allclose(np.column_stack([x, np.ones(50)]) @ T.T, np.column_stack([xn, np.ones(50)]))


def test_linear_fits_are_exact_on_exact_data() -> None:
    x_ref, x_cur = _planar(8)
    xn_ref, T_ref = normalize_points(x_ref)
    xn_cur, T_cur = normalize_points(x_cur)
    H = adjugate(T_cur) @ fit_homographies(xn_ref[None], xn_cur[None])[0] @ T_ref
    mapped = np.column_stack([x_ref, np.ones(8)]) @ H.T
    assert np.allclose(mapped[:, :2] / mapped[:, 2:], x_cur, atol=1e-6)

    x_ref, x_cur = _general(8)
    xn_ref, T_ref = normalize_points(x_ref)
    xn_cur, T_cur = normalize_points(x_cur)
    F = T_cur.T @ fit_fundamentals(xn_ref[None], xn_cur[None])[0] @ T_ref
    assert np.linalg.matrix_rank(F, tol=1e-9 * np.abs(F).max()) == 2
    F_true = _true_F()
    assert np.allclose(F / np.linalg.norm(F) * np.sign(F[2, 2] * F_true[2, 2]), F_true / np.linalg.norm(F_true), atol=1e-6)


def test_scores_count_each_image_below_its_threshold() -> None:
    x_ref, x_cur = _general(10)
    x_cur = x_cur.copy()
    x_cur[0, 1] += 100.0  # far off: an outlier in both images
    inv_sigma2 = np.ones(10)
    score, inliers = score_fundamentals(_true_F()[None], x_ref, x_cur, inv_sigma2)
    assert np.array_equal(inliers[0], np.arange(10) > 0)
    # Nine exact matches score the 2-dof threshold in both images; the outlier scores nothing.
    assert math.isclose(score[0], 9 * 2 * CHI2_2DOF, rel_tol=1e-9)
    x_ref, x_cur = _planar(10)
    x_cur = x_cur.copy()
    x_cur[3, 0] += 2.0  # 4 px^2 of transfer error: still an inlier, scoring less in both images
    H = K @ (R_TRUE + np.outer(T_TRUE, [-0.3, -0.2, 1.0]) / 5.0) @ np.linalg.inv(K)  # the plane n.p = 5
    score, inliers = score_homographies(H[None], x_ref, x_cur, inv_sigma2)
    assert inliers[0].all()
    assert 10 * 2 * CHI2_2DOF - 2 * 4.0 - 1.0 < score[0] < 10 * 2 * CHI2_2DOF - 2 * 4.0 + 1.0
    _, inliers_tight = score_homographies(H[None], x_ref, x_cur, inv_sigma2 * 4.0)  # sigma 0.5 px
    assert np.array_equal(inliers_tight[0], np.arange(10) != 3)
    assert CHI2_1DOF < CHI2_2DOF


def test_ransac_finds_the_model_through_outliers() -> None:
    x_ref, x_cur = _general(300, seed=1)
    rng = np.random.default_rng(2)
    outlier = rng.random(300) < 0.3
    x_cur = x_cur.copy()
    x_cur[outlier] = rng.uniform([0, 0], [640, 480], (int(outlier.sum()), 2))
    sets = draw_sample_sets(300, 200, np.random.default_rng(0))
    fit = find_fundamental(x_ref, x_cur, sets, np.ones(300))
    assert fit is not None
    assert fit.inliers[~outlier].all()
    assert fit.inliers[outlier].mean() < 0.05
    fit_h = find_homography(x_ref, x_cur, sets, np.ones(300))
    assert fit_h is not None and fit_h.score < 0.5 * fit.score  # a general scene is no plane


def test_refinement_returns_to_the_true_motion() -> None:
    x_ref, x_cur = _general(400, seed=5)
    start_R = so3_exp(np.array([0.01, -0.01, 0.005])) @ R_TRUE
    start_t = T_TRUE / np.linalg.norm(T_TRUE) + np.array([0.0, 0.05, -0.08])
    start_t /= np.linalg.norm(start_t)
    R, t = refine_motion(start_R, start_t, x_ref, x_cur, K, np.ones(400), 20)
    assert np.linalg.norm(so3_log(R @ R_TRUE.T)) < 1e-5
    assert np.linalg.norm(t - T_TRUE / np.linalg.norm(T_TRUE)) < 1e-5
    assert math.isclose(np.linalg.norm(t), 1.0, rel_tol=1e-12)
