"""Rigid-body helpers: 4x4 homogeneous transforms and quaternion conventions made explicit."""

from __future__ import annotations

import math

import numpy as np


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Build a 4x4 transform from a 3x3 rotation and a 3-vector translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def invert_T(T: np.ndarray) -> np.ndarray:
    """Invert a rigid 4x4 transform (or a stack of them, shape (..., 4, 4)) exactly."""
    T = np.asarray(T, dtype=float)
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def transform_points(T_a_b: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """Map points (N, 3) from frame b to frame a."""
    p_b = np.asarray(p_b, dtype=float)
    return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def skew(w: np.ndarray) -> np.ndarray:
    """The 3x3 cross-product matrix of a 3-vector."""
    x, y, z = np.asarray(w, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrix of the rotation vector w (radians)."""
    w = np.asarray(w, dtype=float)
    theta = float(np.linalg.norm(w))
    K = skew(w)
    if theta < 1e-10:
        return np.eye(3) + K
    a = np.sin(theta) / theta
    b = (1.0 - np.cos(theta)) / theta**2
    return np.eye(3) + a * K + b * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (radians) of a rotation matrix."""
    cos_theta = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(cos_theta))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-10:
        return 0.5 * v
    if np.pi - theta < 1e-6:
        # Near pi the antisymmetric part vanishes; take the axis from the symmetric part.
        M = (R + np.eye(3)) / 2.0
        axis = np.sqrt(np.clip(np.diag(M), 0.0, None))
        i = int(np.argmax(axis))
        axis = M[i] / axis[i]
        return theta * axis / np.linalg.norm(axis)
    return theta / (2.0 * np.sin(theta)) * v


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """4x4 exponential of xi = (omega rad, upsilon m)."""
    omega, upsilon = xi[:3], xi[3:]
    theta = float(np.linalg.norm(omega))
    K = skew(omega)
    if theta < 1e-8:
        V = np.eye(3) + 0.5 * K
    else:
        V = np.eye(3) + (1.0 - math.cos(theta)) / theta**2 * K + (theta - math.sin(theta)) / theta**3 * (K @ K)
    T = np.eye(4)
    T[:3, :3] = so3_exp(omega)
    T[:3, 3] = V @ upsilon
    return T


def se3_log(T: np.ndarray) -> np.ndarray:
    """xi = (omega rad, upsilon m) with se3_exp(xi) = T (rotation angle below pi)."""
    omega = so3_log(T[:3, :3])
    theta = float(np.linalg.norm(omega))
    K = skew(omega)
    V_inv = np.eye(3) - 0.5 * K
    if theta >= 1e-8:
        V_inv += (1.0 - theta * math.sin(theta) / (2.0 * (1.0 - math.cos(theta)))) / theta**2 * (K @ K)
    return np.concatenate([omega, V_inv @ T[:3, 3]])


def se3_adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint of T on xi = (omega, upsilon): T @ se3_exp(xi) @ inv(T) = se3_exp(adjoint @ xi)."""
    R, t = T[:3, :3], T[:3, 3]
    adjoint = np.zeros((6, 6))
    adjoint[:3, :3] = R
    adjoint[3:, 3:] = R
    adjoint[3:, :3] = skew(t) @ R
    return adjoint


def quat_wxyz_to_R(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion given as (w, x, y, z); the input is normalised."""
    w, x, y, z = np.asarray(q_wxyz, dtype=float) / np.linalg.norm(q_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def R_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def quat_xyzw_to_wxyz(q_xyzw: np.ndarray) -> np.ndarray:
    """Reorder a quaternion from (x, y, z, w) to (w, x, y, z)."""
    q = np.asarray(q_xyzw, dtype=float)
    return q[..., [3, 0, 1, 2]]


def quat_wxyz_to_xyzw(q_wxyz: np.ndarray) -> np.ndarray:
    """Reorder a quaternion from (w, x, y, z) to (x, y, z, w)."""
    q = np.asarray(q_wxyz, dtype=float)
    return q[..., [1, 2, 3, 0]]
