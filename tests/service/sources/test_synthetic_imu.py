"""Synthetic IMU: integrating the samples reproduces the ground-truth motion; noise and bias as configured."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.geometry import so3_exp, so3_log
from zenslam.service.sources.synthetic import SyntheticSource, scene_config

GRAVITY = np.array([0.0, 0.0, -9.81])


def imu_poses(source: SyntheticSource, t_s: np.ndarray) -> np.ndarray:
    """Ground-truth T_world_imu (N, 4, 4) from the camera poses and T_cam_imu."""
    return source.trajectory.T_world_cam(t_s) @ source.imu().T_cam_imu


@pytest.mark.parametrize("name, t0", [("loop", 3.0), ("loop", 17.5), ("figure_eight", 8.0)])
def test_integrating_one_second_of_imu_reproduces_ground_truth(name: str, t0: float) -> None:
    source = SyntheticSource(scene_config(name))
    imu = source.imu()
    rate = source.config.imu_rate_hz
    first = int(round(t0 * rate))
    steps = int(rate)  # one second
    gyro = imu.gyro_rad_s[first : first + steps + 1]
    accel = imu.accel_m_s2[first : first + steps + 1]
    t = (imu.stamps_ns[first : first + steps + 1] - imu.stamps_ns[0]) / 1e9
    dt = 1.0 / rate

    T0, T1 = imu_poses(source, np.array([t[0], t[-1]]))
    h = 1e-4  # initial velocity from the poses alone (central difference)
    before, after = imu_poses(source, np.array([t[0] - h, t[0] + h]))
    R, p, v = T0[:3, :3].copy(), T0[:3, 3].copy(), (after[:3, 3] - before[:3, 3]) / (2 * h)
    for k in range(steps):
        R_next = R @ so3_exp(0.5 * (gyro[k] + gyro[k + 1]) * dt)  # midpoint rotation
        a_k, a_next = R @ accel[k] + GRAVITY, R_next @ accel[k + 1] + GRAVITY
        v_next = v + 0.5 * (a_k + a_next) * dt  # trapezoid
        p = p + 0.5 * (v + v_next) * dt
        R, v = R_next, v_next

    rotation_error = np.linalg.norm(so3_log(T1[:3, :3].T @ R))
    assert rotation_error < 1e-3
    assert np.linalg.norm(p - T1[:3, 3]) < 0.01
    assert np.linalg.norm(T1[:3, 3] - T0[:3, 3]) > 0.2, "the test needs real motion to mean anything"


def test_still_imu_reads_gravity_and_no_rotation() -> None:
    source = SyntheticSource(scene_config("still"))
    imu = source.imu()
    assert len(imu.stamps_ns) == 5 * 200 + 1
    assert np.all(np.diff(imu.stamps_ns) == 5_000_000)
    np.testing.assert_allclose(imu.gyro_rad_s, 0.0, atol=1e-15)
    R_world_imu = (source.ground_truth().T_world_cam[0] @ imu.T_cam_imu)[:3, :3]
    expected = np.tile(R_world_imu.T @ [0.0, 0.0, 9.81], (len(imu.stamps_ns), 1))
    np.testing.assert_allclose(imu.accel_m_s2, expected, atol=1e-12)


def test_noise_and_bias_follow_the_config_deterministically() -> None:
    clean = SyntheticSource(scene_config("loop", duration_s=10.0)).imu()
    noisy_config = scene_config(
        "loop",
        duration_s=10.0,
        gyro_noise_std_rad_s=0.01,
        accel_noise_std_m_s2=0.05,
        gyro_bias_rad_s=(0.001, -0.002, 0.003),
        accel_bias_m_s2=(0.1, 0.0, -0.2),
    )
    noisy = SyntheticSource(noisy_config).imu()
    again = SyntheticSource(noisy_config).imu()
    assert noisy.gyro_rad_s.tobytes() == again.gyro_rad_s.tobytes()
    assert noisy.accel_m_s2.tobytes() == again.accel_m_s2.tobytes()
    gyro_error, accel_error = noisy.gyro_rad_s - clean.gyro_rad_s, noisy.accel_m_s2 - clean.accel_m_s2
    np.testing.assert_allclose(gyro_error.mean(axis=0), [0.001, -0.002, 0.003], atol=0.01 * 4 / np.sqrt(2001))
    np.testing.assert_allclose(accel_error.mean(axis=0), [0.1, 0.0, -0.2], atol=0.05 * 4 / np.sqrt(2001))
    np.testing.assert_allclose(gyro_error.std(axis=0), 0.01, rtol=0.1)
    np.testing.assert_allclose(accel_error.std(axis=0), 0.05, rtol=0.1)
    other_seed = SyntheticSource(scene_config("loop", duration_s=10.0, seed=3, gyro_noise_std_rad_s=0.01)).imu()
    assert not np.array_equal(other_seed.gyro_rad_s, noisy.gyro_rad_s - noisy_config.gyro_bias_rad_s)


def test_t_cam_imu_is_the_configured_rigid_transform() -> None:
    config = scene_config("loop", cam_imu_translation_m=(0.1, 0.2, -0.05), cam_imu_rotvec_rad=(0.0, 0.3, 0.0))
    T = SyntheticSource(config).imu().T_cam_imu
    np.testing.assert_allclose(T[:3, 3], [0.1, 0.2, -0.05])
    np.testing.assert_allclose(so3_log(T[:3, :3]), [0.0, 0.3, 0.0], atol=1e-12)
