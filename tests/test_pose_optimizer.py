"""Pose-only optimisation recovers known poses from synthetic observations with gross outliers."""

import dataclasses

import numpy as np
import pytest

import zenslam.pose_optimizer as pose_optimizer
from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError
from zenslam.pose_optimizer import PoseOptimizerConfig, optimize_pose
from zenslam.geometry import invert_T, make_T, se3_exp, so3_exp, so3_log
from zenslam.config import from_mapping

STEREO = PinholeCalibration(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370, baseline_m=0.5372)
MONO = PinholeCalibration(458.654, 457.296, 367.215, 248.375, 752, 480)


def make_scene(n, seed, calibration=STEREO, stereo_fraction=0.5, outlier_fraction=0.3, noise_px=1.0):
    """Points seen by a known camera, 1 px noise, random-pixel outliers, a start 10 cm / 5 deg off."""
    rng = np.random.default_rng(seed)
    T_true = make_T(so3_exp(rng.normal(scale=0.3, size=3)), rng.normal(scale=5.0, size=3))
    u = rng.uniform(0, calibration.width, n)
    v = rng.uniform(0, calibration.height, n)
    z = rng.uniform(2.0, 40.0, n)
    p_cam = np.stack([(u - calibration.cx) * z / calibration.fx, (v - calibration.cy) * z / calibration.fy, z], 1)
    p_world = (p_cam - T_true[:3, 3]) @ T_true[:3, :3]
    level = rng.integers(0, 8, n)
    obs_px = np.stack([u, v], 1) + rng.normal(scale=noise_px, size=(n, 2))
    stereo = rng.random(n) < stereo_fraction
    bf = calibration.bf if calibration.baseline_m else 0.0
    obs_right_u = np.where(stereo, u - bf / z + rng.normal(scale=noise_px, size=n), np.nan)
    outlier = rng.random(n) < outlier_fraction
    obs_px[outlier] = rng.uniform([0, 0], [calibration.width, calibration.height], (int(outlier.sum()), 2))
    bad = outlier & stereo
    obs_right_u[bad] = obs_px[bad, 0] - rng.uniform(1.0, 100.0, int(bad.sum()))
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    delta = make_T(so3_exp(np.deg2rad(5.0) * axis / np.linalg.norm(axis)), 0.1 * direction / np.linalg.norm(direction))
    inv_sigma2 = 1.2 ** (-2.0 * level)
    return T_true, delta @ T_true, p_world, obs_px, obs_right_u, inv_sigma2, outlier


def pose_errors(T_est, T_true):
    position = np.linalg.norm(invert_T(T_est)[:3, 3] - invert_T(T_true)[:3, 3])
    rotation = np.rad2deg(np.linalg.norm(so3_log(T_est[:3, :3] @ T_true[:3, :3].T)))
    return position, rotation


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_pose_and_flags_outliers_with_mixed_stereo_and_mono(seed):
    T_true, T_init, p_world, obs_px, obs_right_u, inv_sigma2, outlier = make_scene(400, seed)
    result = optimize_pose(T_init, p_world, obs_px, obs_right_u, inv_sigma2, STEREO, PoseOptimizerConfig())
    position, rotation = pose_errors(result.T_cam_world, T_true)
    assert position < 0.02
    assert rotation < 0.2
    assert (~result.inliers[outlier]).mean() > 0.95  # outliers flagged
    assert result.inliers[~outlier].mean() > 0.95  # inliers kept
    assert result.n_inliers == int(result.inliers.sum())
    assert result.rounds == 4 and 0 < result.iterations <= 40
    np.testing.assert_allclose(result.T_cam_world[:3, :3] @ result.T_cam_world[:3, :3].T, np.eye(3), atol=1e-12)


def test_recovers_pose_from_mono_observations_without_a_baseline():
    T_true, T_init, p_world, obs_px, obs_right_u, inv_sigma2, outlier = make_scene(
        400, 3, calibration=MONO, stereo_fraction=0.0
    )
    result = optimize_pose(T_init, p_world, obs_px, obs_right_u, inv_sigma2, MONO, PoseOptimizerConfig())
    position, rotation = pose_errors(result.T_cam_world, T_true)
    assert position < 0.02 and rotation < 0.2
    assert (~result.inliers[outlier]).mean() > 0.95 and result.inliers[~outlier].mean() > 0.95


def test_exact_observations_give_exact_pose_and_zero_chi2():
    T_true, T_init, p_world, obs_px, obs_right_u, inv_sigma2, _ = make_scene(50, 4, outlier_fraction=0.0, noise_px=0.0)
    result = optimize_pose(T_init, p_world, obs_px, obs_right_u, inv_sigma2, STEREO, PoseOptimizerConfig())
    np.testing.assert_allclose(result.T_cam_world, T_true, atol=1e-8)
    assert result.inliers.all()
    assert np.all(result.chi2 < 1e-10)


def test_negative_right_u_means_mono_observation():
    _, T_init, p_world, obs_px, obs_right_u, inv_sigma2, _ = make_scene(100, 5)
    with_nan = optimize_pose(T_init, p_world, obs_px, obs_right_u, inv_sigma2, STEREO, PoseOptimizerConfig())
    with_negative = optimize_pose(
        T_init, p_world, obs_px, np.nan_to_num(obs_right_u, nan=-1.0), inv_sigma2, STEREO, PoseOptimizerConfig()
    )
    np.testing.assert_array_equal(with_nan.T_cam_world, with_negative.T_cam_world)
    np.testing.assert_array_equal(with_nan.inliers, with_negative.inliers)


def test_results_are_deterministic():
    _, T_init, p_world, obs_px, obs_right_u, inv_sigma2, _ = make_scene(200, 6)
    a = optimize_pose(T_init, p_world, obs_px, obs_right_u, inv_sigma2, STEREO, PoseOptimizerConfig())
    b = optimize_pose(T_init, p_world, obs_px, obs_right_u, inv_sigma2, STEREO, PoseOptimizerConfig())
    np.testing.assert_array_equal(a.T_cam_world, b.T_cam_world)
    np.testing.assert_array_equal(a.inliers, b.inliers)
    np.testing.assert_array_equal(a.chi2, b.chi2)


@pytest.mark.parametrize("n", [0, 1, 2])
def test_fewer_than_three_observations_is_no_pose(n):
    _, T_init, p_world, obs_px, obs_right_u, inv_sigma2, _ = make_scene(5, 7, outlier_fraction=0.0)
    result = optimize_pose(
        T_init, p_world[:n], obs_px[:n], obs_right_u[:n], inv_sigma2[:n], STEREO, PoseOptimizerConfig()
    )
    assert result.n_inliers == 0
    assert result.inliers.shape == (n,) and not result.inliers.any()
    assert result.iterations == 0
    np.testing.assert_array_equal(result.T_cam_world, T_init)


def test_points_behind_the_camera_are_all_outliers_and_the_pose_stays():
    _, T_init, p_world, obs_px, obs_right_u, inv_sigma2, _ = make_scene(30, 8, outlier_fraction=0.0)
    p_cam = p_world @ T_init[:3, :3].T + T_init[:3, 3]
    p_cam[:, 2] *= -1.0  # mirror every point behind the camera
    p_world_behind = (p_cam - T_init[:3, 3]) @ T_init[:3, :3]
    result = optimize_pose(T_init, p_world_behind, obs_px, obs_right_u, inv_sigma2, STEREO, PoseOptimizerConfig())
    assert result.n_inliers == 0 and not result.inliers.any()
    assert np.all(np.isinf(result.chi2))
    np.testing.assert_allclose(result.T_cam_world, T_init, atol=1e-12)


def test_non_finite_rows_are_ignored_and_never_inliers():
    T_true, T_init, p_world, obs_px, obs_right_u, inv_sigma2, _ = make_scene(100, 9, outlier_fraction=0.0)
    p_world[:5] = np.nan
    result = optimize_pose(T_init, p_world, obs_px, obs_right_u, inv_sigma2, STEREO, PoseOptimizerConfig())
    assert not result.inliers[:5].any() and np.isnan(result.chi2[:5]).all()
    assert pose_errors(result.T_cam_world, T_true)[0] < 0.02


def test_stereo_observations_need_a_baseline():
    _, T_init, p_world, obs_px, obs_right_u, inv_sigma2, _ = make_scene(20, 10)
    with pytest.raises(CalibrationError, match="baseline"):
        optimize_pose(T_init, p_world, obs_px, obs_right_u, inv_sigma2, MONO, PoseOptimizerConfig())


def test_mismatched_shapes_name_the_argument():
    _, T_init, p_world, obs_px, obs_right_u, inv_sigma2, _ = make_scene(20, 11)
    with pytest.raises(ValueError, match="obs_px"):
        optimize_pose(T_init, p_world, obs_px[:10], obs_right_u, inv_sigma2, STEREO, PoseOptimizerConfig())


@pytest.mark.parametrize("weighted", [False, True])
def test_normal_equations_match_finite_difference_jacobians(weighted):
    # H = J^T W J and g = J^T W r of the compiled pass, against J from central differences of the
    # residuals under the left perturbation T <- exp(xi) T; W per observation or inv_sigma2 I.
    rng = np.random.default_rng(12)
    p_world = rng.normal(size=(6, 3)) + [0.0, 0.0, 6.0]
    usable = np.ones(6, dtype=bool)
    problem = pose_optimizer._make_problem(
        p_world, rng.normal(size=(6, 2)), np.array([1.0, -1, 1, 1, -1, 1]), rng.uniform(0.3, 1.0, 6), usable, STEREO, PoseOptimizerConfig()
    )
    if weighted:
        A = rng.normal(size=(6, 3, 3))
        present = problem.row_mask[:, :, None] * problem.row_mask[:, None, :]
        problem = dataclasses.replace(problem, information=(A @ A.transpose(0, 2, 1) + np.eye(3)) * present)
    T = make_T(so3_exp([0.1, -0.2, 0.05]), [0.3, -0.1, 0.2])
    _, residual = pose_optimizer._project(T, problem)
    J = np.zeros((6, 3, 6))
    for k in range(6):
        step = np.zeros(6)
        step[k] = 1e-6
        _, plus = pose_optimizer._project(se3_exp(step) @ T, problem)
        _, minus = pose_optimizer._project(se3_exp(-step) @ T, problem)
        J[:, :, k] = (plus - minus) / 2e-6
    W = problem.information if weighted else problem.inv_sigma2[:, None, None] * np.eye(3) * problem.row_mask[:, :, None]
    cost, H, g = pose_optimizer._linearize(T, problem, robust=False, min_depth_m=1e-3)
    np.testing.assert_allclose(H, np.einsum("nki,nkl,nlj->ij", J, W, J), rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(g, np.einsum("nki,nkl,nl->i", J, W, residual), rtol=1e-5, atol=1e-3)
    assert cost == pytest.approx(float(np.einsum("nk,nkl,nl->", residual, W, residual)), rel=1e-12)


def test_config_builds_from_a_mapping():
    config = from_mapping(PoseOptimizerConfig, {"rounds": 2, "chi2_mono": 6.0})
    assert config.rounds == 2 and config.chi2_mono == 6.0 and config.iterations_per_round == 10


def _noisy_observations(T_true, p_world, calibration, rng, noise_px):
    p_cam = p_world @ T_true[:3, :3].T + T_true[:3, 3]
    u = calibration.fx * p_cam[:, 0] / p_cam[:, 2] + calibration.cx
    v = calibration.fy * p_cam[:, 1] / p_cam[:, 2] + calibration.cy
    right = u - calibration.bf / p_cam[:, 2]
    n = len(p_world)
    return np.stack([u, v], 1) + rng.normal(scale=noise_px, size=(n, 2)), right + rng.normal(scale=noise_px, size=n)


def test_position_sigma_is_the_spread_of_the_centre_under_pixel_noise():
    """Monte Carlo: the camera centres optimised from 300 draws of 1 px noise spread as position_sigma says."""
    rng = np.random.default_rng(4)
    T_true, _, p_world, _, _, _, _ = make_scene(150, 3, outlier_fraction=0.0)
    inv_sigma2 = np.ones(len(p_world))
    centres = []
    for _ in range(300):
        obs_px, right = _noisy_observations(T_true, p_world, STEREO, rng, 1.0)
        result = optimize_pose(T_true, p_world, obs_px, right, inv_sigma2, STEREO, PoseOptimizerConfig(rounds=1, robust_rounds=0))
        centres.append(invert_T(result.T_cam_world)[:3, 3])
    largest_std = float(np.sqrt(np.linalg.eigvalsh(np.cov(np.array(centres).T))[-1]))
    obs_px, right = _noisy_observations(T_true, p_world, STEREO, rng, 0.0)
    sigma = pose_optimizer.position_sigma(T_true, p_world, obs_px, right, inv_sigma2, STEREO)
    assert 0.85 < largest_std / sigma < 1.15, (largest_std, sigma)


def test_position_sigma_grows_when_the_points_are_far_and_on_one_plane():
    """Near points spread in depth pin the centre down; far points on one plane leave it loose
    sideways (sideways motion and rotation look alike)."""
    rng = np.random.default_rng(5)
    u = rng.uniform(100, STEREO.width - 100, 200)
    v = rng.uniform(50, STEREO.height - 50, 200)

    def sigma_for(depth):
        p_cam = np.stack([(u - STEREO.cx) * depth / STEREO.fx, (v - STEREO.cy) * depth / STEREO.fy, depth], 1)
        obs_px, right = _noisy_observations(np.eye(4), p_cam, STEREO, rng, 0.0)
        return pose_optimizer.position_sigma(np.eye(4), p_cam, obs_px, right, np.ones(200), STEREO)

    near = sigma_for(rng.uniform(3.0, 12.0, 200))
    far_plane = sigma_for(np.full(200, 60.0))
    assert far_plane > 20 * near
    assert pose_optimizer.position_sigma(np.eye(4), np.zeros((2, 3)), np.zeros((2, 2)), np.full(2, np.nan), np.ones(2), STEREO) == np.inf


def test_zero_point_covariance_is_the_plain_problem():
    _, T_init, p_world, obs_px, obs_right_u, inv_sigma2, _ = make_scene(200, 8)
    args = (T_init, p_world, obs_px, obs_right_u, inv_sigma2, STEREO, PoseOptimizerConfig())
    plain, zero = optimize_pose(*args), optimize_pose(*args, point_covariance=np.zeros((200, 3, 3)))
    assert np.array_equal(plain.T_cam_world, zero.T_cam_world) and np.array_equal(plain.inliers, zero.inliers)
    with pytest.raises(ValueError, match="point_covariance"):
        optimize_pose(*args, point_covariance=np.zeros((199, 3, 3)))


@pytest.mark.parametrize("stereo_fraction", [0.0, 0.7])
def test_a_point_covariance_takes_the_pull_of_points_known_only_roughly_along_it(stereo_fraction):
    """Half the points are 0.4 m off along the camera's x axis (as far points mapped from the side
    are off along their depth). Taken as exact they drag the pose sideways; with a covariance of
    0.4 m along that axis they hardly do, and their chi-square no longer makes them outliers."""
    calibration = MONO if stereo_fraction == 0.0 else STEREO
    T_true, T_init, p_world, obs_px, obs_right_u, inv_sigma2, _ = make_scene(
        300, 9, calibration=calibration, stereo_fraction=stereo_fraction, outlier_fraction=0.0, noise_px=0.3
    )
    off = np.arange(300) % 2 == 0
    axis = T_true[0, :3]  # the camera's x axis in the world frame
    moved = p_world + np.where(off[:, None], 0.4 * axis, 0.0)
    covariance = np.where(off[:, None, None], 0.4**2 * np.outer(axis, axis), 0.0)
    args = (T_init, moved, obs_px, obs_right_u, inv_sigma2, calibration, PoseOptimizerConfig())
    plain = optimize_pose(*args)
    weighed = optimize_pose(*args, point_covariance=covariance)
    plain_error, _ = pose_errors(plain.T_cam_world, T_true)
    weighed_error, _ = pose_errors(weighed.T_cam_world, T_true)
    assert plain_error > 0.05 and weighed_error < 0.25 * plain_error, (plain_error, weighed_error)
    assert weighed.inliers[off].mean() > 0.9 and weighed.inliers[~off].mean() > 0.9
