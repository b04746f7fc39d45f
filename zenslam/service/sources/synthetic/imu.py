"""IMU measurements synthesised exactly from an analytic trajectory: gyro and specific force in the IMU frame.

World frame z up with gravity g_world = (0, 0, -9.81) m/s^2. The accelerometer measures the specific
force R_world_imu^T (a_world_imu - g_world), so a resting IMU reads +9.81 m/s^2 along world up.
"""

from __future__ import annotations

import math

import numpy as np

from zenslam.geometry import make_T, so3_exp
from zenslam.service.sources.frame import ImuSamples
from zenslam.service.sources.synthetic.config import SceneConfig
from zenslam.service.sources.synthetic.trajectories import AnalyticTrajectory

GRAVITY_WORLD_M_S2 = np.array([0.0, 0.0, -9.81])


def T_cam_imu(config: SceneConfig) -> np.ndarray:
    """The 4x4 transform mapping IMU coordinates to the (left) camera frame."""
    return make_T(so3_exp(np.asarray(config.cam_imu_rotvec_rad)), np.asarray(config.cam_imu_translation_m))


def imu_times_s(config: SceneConfig) -> np.ndarray:
    """Sample times (seconds from the first frame) at ``imu_rate_hz`` covering [0, duration_s]."""
    count = int(math.floor(config.duration_s * config.imu_rate_hz + 1e-9)) + 1
    return np.arange(count) / config.imu_rate_hz


def ideal_imu(trajectory: AnalyticTrajectory, T_cam_imu: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free gyro (rad/s) and specific force (m/s^2), both (N, 3) in the IMU frame, at times ``t_s``.

    The IMU sits at lever arm r = R_world_cam t_cam_imu from the camera centre, so its acceleration
    adds alpha x r + omega x (omega x r) to the camera's.
    """
    kin = trajectory.kinematics(t_s)
    R_world_imu = kin.R_world_cam @ T_cam_imu[:3, :3]
    r_world = kin.R_world_cam @ T_cam_imu[:3, 3]
    lever = np.cross(kin.alpha_world, r_world) + np.cross(kin.omega_world, np.cross(kin.omega_world, r_world))
    a_imu = kin.a_world + lever
    R_imu_world = np.swapaxes(R_world_imu, 1, 2)
    gyro = np.einsum("nij,nj->ni", R_imu_world, kin.omega_world)
    accel = np.einsum("nij,nj->ni", R_imu_world, a_imu - GRAVITY_WORLD_M_S2)
    return gyro, accel


def synthesize_imu(trajectory: AnalyticTrajectory, config: SceneConfig) -> ImuSamples:
    """IMU samples for the whole sequence, with the configured constant bias and white noise (seeded)."""
    T = T_cam_imu(config)
    t_s = imu_times_s(config)
    gyro, accel = ideal_imu(trajectory, T, t_s)
    gyro = gyro + np.asarray(config.gyro_bias_rad_s)
    accel = accel + np.asarray(config.accel_bias_m_s2)
    rng = np.random.default_rng([config.seed, 0x1A0])
    if config.gyro_noise_std_rad_s > 0:
        gyro = gyro + rng.normal(0.0, config.gyro_noise_std_rad_s, size=gyro.shape)
    if config.accel_noise_std_m_s2 > 0:
        accel = accel + rng.normal(0.0, config.accel_noise_std_m_s2, size=accel.shape)
    stamps = config.start_stamp_ns + np.round(np.arange(len(t_s)) * (1e9 / config.imu_rate_hz)).astype(np.int64)
    return ImuSamples(stamps_ns=stamps, gyro_rad_s=gyro, accel_m_s2=accel, T_cam_imu=T)
