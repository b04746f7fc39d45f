"""Localisation mode's pose filter (``frontend/pose_filter.py``): prediction and fusion. What it
changes against ORB-SLAM2's exact VO points is tested in test_tracker.py."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.frontend.pose_filter import PoseEstimate, fuse, predict
from zenslam.geometry import invert_T, make_T, se3_adjoint, se3_exp, se3_log, so3_exp


def test_se3_log_inverts_exp_and_the_adjoint_moves_a_perturbation_across_a_transform() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        xi = rng.normal(size=6) * 0.8
        assert np.allclose(se3_log(se3_exp(xi)), xi, atol=1e-9)
        T, e = se3_exp(rng.normal(size=6)), rng.normal(size=6) * 0.3
        assert np.allclose(T @ se3_exp(e) @ invert_T(T), se3_exp(se3_adjoint(T) @ e), atol=1e-9)


def test_a_prediction_carries_the_sources_covariance_and_adds_the_odometrys() -> None:
    source = PoseEstimate(np.eye(4), np.diag([1e-4, 2e-4, 3e-4, 1e-2, 2e-2, 3e-2]))
    odometry_information = np.diag([1e6] * 3 + [1e4] * 3)
    still = predict(source, np.eye(4), odometry_information)
    assert np.allclose(still.covariance, source.covariance + np.linalg.inv(odometry_information), rtol=1e-6)
    turned = make_T(so3_exp(np.array([0.0, 0.5, 0.0])), np.array([1.0, 0.0, 0.0]))
    moved = predict(source, turned, odometry_information)
    carry = se3_adjoint(turned)
    assert np.allclose(moved.covariance, carry @ source.covariance @ carry.T + np.linalg.inv(odometry_information), rtol=1e-6)
    assert np.array_equal(moved.T_cam_world, turned)
    blind = predict(source, np.eye(4), np.zeros((6, 6)))  # no VO point: the prediction says nothing
    assert np.all(np.diag(blind.covariance) > 1e8)


def test_fusion_weighs_the_map_and_the_prediction_by_their_information() -> None:
    offset = np.array([0.0, 0.0, 0.0, 0.04, 0.0, 0.0])
    T_map, T_predicted = np.eye(4), se3_exp(offset)
    information = np.eye(6) * 1e4
    equal = fuse(T_map, information, PoseEstimate(T_predicted, np.linalg.inv(information)))
    assert np.allclose(se3_log(equal.T_cam_world), offset / 2, atol=1e-9)
    assert np.allclose(equal.covariance, np.linalg.inv(2 * information), rtol=1e-6)
    vague = fuse(T_map, information, PoseEstimate(T_predicted, np.eye(6) * 1e6))
    assert np.linalg.norm(se3_log(vague.T_cam_world)) < 1e-9  # the map's pose
    blind = fuse(T_map, np.zeros((6, 6)), PoseEstimate(T_predicted, np.linalg.inv(information)))
    assert np.allclose(se3_log(blind.T_cam_world), offset, atol=1e-9)  # the prediction's pose


def test_a_map_pose_that_fails_the_innovation_test_replaces_the_prediction() -> None:
    """4 cm apart with 1 cm standard deviations each: chi2 = 8 (6 dof), averaged below the 99.9%
    threshold 22.46, the map's pose alone (and its covariance) above a threshold of 5."""
    information = np.eye(6) * 1e4
    predicted = PoseEstimate(se3_exp(np.array([0.0, 0.0, 0.0, 0.04, 0.0, 0.0])), np.linalg.inv(information))
    averaged = fuse(np.eye(4), information, predicted, max_chi2=22.46)
    assert np.isclose(se3_log(averaged.T_cam_world)[3], 0.02)
    reset = fuse(np.eye(4), information, predicted, max_chi2=5.0)
    assert np.array_equal(reset.T_cam_world, np.eye(4)) and np.allclose(reset.covariance, np.linalg.inv(information), rtol=1e-6)


def test_the_filters_settings_are_checked() -> None:
    from zenslam.errors import ConfigError
    from zenslam.frontend.visual_odometry import VisualOdometryConfig

    for bad in ({"filter_max_chi2": 0.0}, {"filter_map_information_scale": 0.0}, {"filter_map_information_scale": float("nan")}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            VisualOdometryConfig(**bad)
