"""Analytic trajectories of the synthetic scenes: closure, stillness, clearance and exact derivatives."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.geometry import so3_log
from zenslam.service.sources.synthetic import scene_config
from zenslam.service.sources.synthetic.scene import Quad, room_surfaces
from zenslam.service.sources.synthetic.trajectories import make_trajectory


def distance_to_rectangle(p: np.ndarray, quad: Quad) -> np.ndarray:
    """Euclidean distance (N,) from points p (N, 3) to the rectangle ``quad``."""
    rel = p - quad.origin_world
    s = np.clip(rel @ quad.axis_s, 0.0, quad.size_m[0])
    t = np.clip(rel @ quad.axis_t, 0.0, quad.size_m[1])
    return np.linalg.norm(p - quad.point(s, t), axis=1)


def test_loop_returns_exactly_to_its_start_pose() -> None:
    config = scene_config("loop")
    T = make_trajectory(config).T_world_cam(np.array([0.0, config.duration_s]))
    np.testing.assert_allclose(T[1], T[0], atol=1e-9)
    # ... and it does move in between: an ellipse of 5 x 3 m.
    positions = make_trajectory(config).kinematics(np.linspace(0, config.duration_s, 400)).p_world
    assert np.ptp(positions[:, 0]) == pytest.approx(5.0, abs=0.01)
    assert np.ptp(positions[:, 1]) == pytest.approx(3.0, abs=0.01)


def test_figure_eight_laps_close_and_repeat() -> None:
    config = scene_config("figure_eight")
    trajectory = make_trajectory(config)
    lap = config.duration_s / config.laps
    T = trajectory.T_world_cam(np.array([0.0, lap, 2 * lap, 0.3 * lap, 1.3 * lap]))
    np.testing.assert_allclose(T[1], T[0], atol=1e-9)
    np.testing.assert_allclose(T[2], T[0], atol=1e-9)
    np.testing.assert_allclose(T[4], T[3], atol=1e-9)


def test_still_scene_has_zero_motion() -> None:
    trajectory = make_trajectory(scene_config("still"))
    kin = trajectory.kinematics(np.linspace(0.0, 5.0, 11))
    np.testing.assert_array_equal(kin.p_world, np.repeat(kin.p_world[:1], 11, axis=0))
    np.testing.assert_array_equal(kin.R_world_cam, np.repeat(kin.R_world_cam[:1], 11, axis=0))
    for field in (kin.v_world, kin.a_world, kin.omega_world, kin.alpha_world):
        np.testing.assert_array_equal(field, 0.0)


@pytest.mark.parametrize("name", ["loop", "figure_eight", "still"])
def test_camera_keeps_a_metre_from_every_surface_and_looks_level(name: str) -> None:
    config = scene_config(name)
    kin = make_trajectory(config).kinematics(np.arange(0.0, config.duration_s, 0.05))
    nearest = min(distance_to_rectangle(kin.p_world, quad).min() for quad in room_surfaces())
    assert nearest >= 1.0, f"{name}: the camera comes within {nearest:.2f} m of a surface"
    # Camera y (down in the image) stays within ~15 degrees of world down: images stay upright.
    down = kin.R_world_cam[:, :, 1]
    assert np.all(down[:, 2] < -np.cos(np.radians(15)))


@pytest.mark.parametrize("name", ["loop", "figure_eight"])
def test_derivatives_match_finite_differences(name: str) -> None:
    trajectory = make_trajectory(scene_config(name))
    t = np.linspace(0.3, 29.0, 9)
    h = 1e-5
    kin, after, before = trajectory.kinematics(t), trajectory.kinematics(t + h), trajectory.kinematics(t - h)
    np.testing.assert_allclose((after.p_world - before.p_world) / (2 * h), kin.v_world, atol=1e-7)
    np.testing.assert_allclose((after.v_world - before.v_world) / (2 * h), kin.a_world, atol=1e-7)
    np.testing.assert_allclose((after.omega_world - before.omega_world) / (2 * h), kin.alpha_world, atol=1e-7)
    for i in range(len(t)):
        omega = so3_log(after.R_world_cam[i] @ before.R_world_cam[i].T) / (2 * h)
        np.testing.assert_allclose(omega, kin.omega_world[i], atol=1e-7)
    identity = np.broadcast_to(np.eye(3), (len(t), 3, 3))
    np.testing.assert_allclose(kin.R_world_cam @ np.swapaxes(kin.R_world_cam, 1, 2), identity, atol=1e-12)
