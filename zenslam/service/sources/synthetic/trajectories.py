"""Smooth analytic camera trajectories (loop, figure-eight, still, corridor laps) with exact derivatives for IMU synthesis.

World frame: z up, the room floor at z = 0, gravity (0, 0, -9.81) m/s^2. Camera frame: x right,
y down, z forward. Orientation is built from yaw (heading about world z, from +x towards +y),
pitch (nose up positive) and roll (about the viewing direction) of a forward-left-up body whose x
axis is the camera's viewing direction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from zenslam.service.sources.synthetic.config import SceneConfig
from zenslam.service.sources.synthetic.corridor import CorridorLayout, CorridorPath

# Camera axes in the forward-left-up body frame: x_cam = -y_body, y_cam = -z_body, z_cam = x_body.
_R_BODY_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class Harmonic:
    """A scalar function of time t (seconds): offset + sum_k amps[k] * sin(omegas[k] * t + phases[k])."""

    offset: float = 0.0
    amps: tuple[float, ...] = ()
    omegas_rad_s: tuple[float, ...] = ()
    phases_rad: tuple[float, ...] = ()

    def derivative(self, t_s: np.ndarray, order: int) -> np.ndarray:
        """The ``order``-th time derivative (order 0 is the value) at times ``t_s`` (seconds)."""
        t_s = np.asarray(t_s, dtype=float)
        out = np.full(t_s.shape, self.offset if order == 0 else 0.0)
        for amp, omega, phase in zip(self.amps, self.omegas_rad_s, self.phases_rad, strict=True):
            out = out + amp * omega**order * np.sin(omega * t_s + phase + order * (math.pi / 2))
        return out


class ScalarOfTime(Protocol):
    """A scalar function of time with exact derivatives (Harmonic, PathCoordinate)."""

    def derivative(self, t_s: np.ndarray, order: int) -> np.ndarray:
        """The ``order``-th time derivative (order 0 is the value) at times ``t_s`` (seconds)."""
        ...


@dataclass(frozen=True)
class PathCoordinate:
    """World x (axis 0) or y (axis 1) of a position moving along ``path`` at constant speed from its start."""

    path: CorridorPath
    axis: int
    speed_m_s: float

    def derivative(self, t_s: np.ndarray, order: int) -> np.ndarray:
        """The ``order``-th time derivative (0..3) at times ``t_s`` (seconds): metres, m/s, m/s^2, m/s^3."""
        arc_m = self.speed_m_s * np.asarray(t_s, dtype=float)
        return self.path.derivatives(np.atleast_1d(arc_m), order)[:, self.axis] * self.speed_m_s**order


def constant(value: float) -> Harmonic:
    """A Harmonic that never changes."""
    return Harmonic(offset=value)


@dataclass(frozen=True)
class Kinematics:
    """Camera motion at N times, all in the world frame (metres, seconds, radians)."""

    p_world: np.ndarray  # (N, 3) camera centre
    v_world: np.ndarray  # (N, 3) velocity of the camera centre, m/s
    a_world: np.ndarray  # (N, 3) acceleration of the camera centre, m/s^2
    R_world_cam: np.ndarray  # (N, 3, 3)
    omega_world: np.ndarray  # (N, 3) angular velocity, rad/s
    alpha_world: np.ndarray  # (N, 3) angular acceleration, rad/s^2

    def T_world_cam(self) -> np.ndarray:
        """Poses (N, 4, 4) mapping camera coordinates to world."""
        T = np.zeros((len(self.p_world), 4, 4))
        T[:, :3, :3] = self.R_world_cam
        T[:, :3, 3] = self.p_world
        T[:, 3, 3] = 1.0
        return T


def _rot_z(a: np.ndarray) -> np.ndarray:
    c, s, o, i = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, -s, o], -1), np.stack([s, c, o], -1), np.stack([o, o, i], -1)], -2)


def _rot_y(a: np.ndarray) -> np.ndarray:
    c, s, o, i = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, o, s], -1), np.stack([o, i, o], -1), np.stack([-s, o, c], -1)], -2)


def _rot_x(a: np.ndarray) -> np.ndarray:
    c, s, o, i = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([i, o, o], -1), np.stack([o, c, -s], -1), np.stack([o, s, c], -1)], -2)


@dataclass(frozen=True)
class AnalyticTrajectory:
    """Camera centre (x, y, z) and yaw/pitch/roll as harmonics of time; derivatives are exact.

    With ``follow_tangent`` the yaw is the heading of the horizontal velocity plus ``yaw``; otherwise
    ``yaw`` alone. The horizontal velocity must not vanish when following the tangent.
    """

    x: ScalarOfTime
    y: ScalarOfTime
    z: Harmonic
    yaw: Harmonic
    pitch: Harmonic
    roll: Harmonic
    follow_tangent: bool

    def kinematics(self, t_s: np.ndarray) -> Kinematics:
        """Position, orientation and their derivatives at times ``t_s`` (seconds from the first frame)."""
        t_s = np.atleast_1d(np.asarray(t_s, dtype=float))
        p = [np.stack([c.derivative(t_s, k) for c in (self.x, self.y, self.z)], -1) for k in range(4)]
        psi, dpsi, ddpsi = (self.yaw.derivative(t_s, k) for k in range(3))
        if self.follow_tangent:
            heading = _heading_derivatives(p[1], p[2], p[3])
            psi, dpsi, ddpsi = psi + heading[0], dpsi + heading[1], ddpsi + heading[2]
        # Nose-up pitch is a negative rotation about the body's left (y) axis.
        beta, dbeta, ddbeta = (-self.pitch.derivative(t_s, k) for k in range(3))
        phi, dphi, ddphi = (self.roll.derivative(t_s, k) for k in range(3))
        Rz, Ry, Rx = _rot_z(psi), _rot_y(beta), _rot_x(phi)
        R_world_body = Rz @ Ry @ Rx
        e_z = np.array([0.0, 0.0, 1.0])
        u2 = Rz[..., :, 1]  # the pitch axis: body y after yaw
        u3 = (Rz @ Ry)[..., :, 0]  # the roll axis: body x after yaw and pitch
        w_yaw_pitch = dpsi[:, None] * e_z + dbeta[:, None] * u2
        omega = w_yaw_pitch + dphi[:, None] * u3
        alpha = (
            ddpsi[:, None] * e_z
            + ddbeta[:, None] * u2
            + dbeta[:, None] * np.cross(dpsi[:, None] * e_z, u2)
            + ddphi[:, None] * u3
            + dphi[:, None] * np.cross(w_yaw_pitch, u3)
        )
        return Kinematics(p[0], p[1], p[2], R_world_body @ _R_BODY_CAM, omega, alpha)

    def T_world_cam(self, t_s: np.ndarray) -> np.ndarray:
        """Camera poses (N, 4, 4) at times ``t_s`` (seconds)."""
        return self.kinematics(t_s).T_world_cam()


def _heading_derivatives(v: np.ndarray, a: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """atan2(vy, vx) and its first two time derivatives from velocity, acceleration and jerk (N, 3)."""
    num = v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]
    den = v[:, 0] ** 2 + v[:, 1] ** 2
    dnum = v[:, 0] * j[:, 1] - v[:, 1] * j[:, 0]
    dden = 2.0 * (v[:, 0] * a[:, 0] + v[:, 1] * a[:, 1])
    return np.arctan2(v[:, 1], v[:, 0]), num / den, (dnum * den - num * dden) / den**2


def _loop(period_s: float) -> AnalyticTrajectory:
    """Counter-clockwise ellipse (5 x 3 m) at ~1.4 m height, looking a little inwards of the travel direction."""
    w = 2.0 * math.pi / period_s
    return AnalyticTrajectory(
        x=Harmonic(0.0, (2.5,), (w,), (math.pi / 2,)),
        y=Harmonic(0.0, (1.5,), (w,), (0.0,)),
        z=Harmonic(1.4, (0.12,), (2 * w,), (0.0,)),
        yaw=Harmonic(0.35, (0.12,), (3 * w,), (0.0,)),
        pitch=Harmonic(-0.06, (0.04,), (2 * w,), (0.5,)),
        roll=Harmonic(0.0, (0.03,), (w,), (1.0,)),
        follow_tangent=True,
    )


def _figure_eight(period_s: float) -> AnalyticTrajectory:
    """A 6 x 3 m figure-eight (one lap per period) at ~1.4 m height, looking along the path."""
    w = 2.0 * math.pi / period_s
    return AnalyticTrajectory(
        x=Harmonic(0.0, (3.0,), (w,), (0.0,)),
        y=Harmonic(0.0, (1.5,), (2 * w,), (0.0,)),
        z=Harmonic(1.4, (0.1,), (w,), (0.3,)),
        yaw=Harmonic(0.0, (0.1,), (2 * w,), (0.7,)),
        pitch=Harmonic(-0.05, (0.03,), (3 * w,), (0.0,)),
        roll=Harmonic(0.0, (0.025,), (2 * w,), (0.2,)),
        follow_tangent=True,
    )


def _still() -> AnalyticTrajectory:
    """A fixed camera at 1.4 m height looking towards the room's +x,+y corner."""
    return AnalyticTrajectory(
        x=constant(1.0),
        y=constant(-1.0),
        z=constant(1.4),
        yaw=constant(0.6),
        pitch=constant(-0.05),
        roll=constant(0.0),
        follow_tangent=False,
    )


def _corridor(period_s: float) -> AnalyticTrajectory:
    """Laps of the corridor's centre line at constant speed, ~1.4 m high, looking along the corridor with
    small lap-periodic sways of height, heading, pitch and roll (so the motion is not planar)."""
    path = CorridorPath(CorridorLayout())
    speed = path.layout.lap_m / period_s
    w = 2.0 * math.pi / period_s
    return AnalyticTrajectory(
        x=PathCoordinate(path, 0, speed),
        y=PathCoordinate(path, 1, speed),
        z=Harmonic(1.4, (0.1,), (4 * w,), (0.0,)),
        yaw=Harmonic(0.0, (0.05,), (5 * w,), (0.3,)),
        pitch=Harmonic(-0.03, (0.02,), (3 * w,), (0.5,)),
        roll=Harmonic(0.0, (0.02,), (2 * w,), (1.0,)),
        follow_tangent=True,
    )


def make_trajectory(config: SceneConfig) -> AnalyticTrajectory:
    """The trajectory of ``config``: ``laps`` laps of the closed path within ``duration_s``."""
    period_s = config.duration_s / config.laps
    if config.trajectory == "loop":
        return _loop(period_s)
    if config.trajectory == "figure_eight":
        return _figure_eight(period_s)
    if config.trajectory == "corridor":
        return _corridor(period_s)
    return _still()
