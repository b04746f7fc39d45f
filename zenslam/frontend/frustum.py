"""ORB-SLAM's ``isInFrustum`` for many map points at once: projection and visibility verdicts.

The per-point rules it relies on (scale prediction) are shared with the backend in
``zenslam.map_point_rules``; the frontend's local map stores points as arrays (``local_map.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.map_point_rules import predict_scale_level


@dataclass(frozen=True)
class FrustumProjection:
    """Map points projected into a camera, with ORB-SLAM's ``isInFrustum`` verdict per point."""

    visible: np.ndarray  # (M,) bool: in front, inside the image, in scale range, viewing angle ok
    px: np.ndarray  # (M, 2) projected pixels (u, v)
    right_u: np.ndarray  # (M,) projected right-image u = u - bf / z (pixels; nan for mono)
    view_cos: np.ndarray  # (M,) cosine between the viewing ray and the point's mean viewing direction
    level: np.ndarray  # (M,) int64 predicted pyramid level


def project_in_frustum(
    T_cam_world: np.ndarray,
    p_world: np.ndarray,
    normals: np.ndarray,
    min_distance_m: np.ndarray,
    max_distance_m: np.ndarray,
    calibration: PinholeCalibration,
    scale_factor: float,
    n_levels: int,
    min_view_cos: float = 0.5,
) -> FrustumProjection:
    """Project points (M, 3, world, metres) with the world -> camera pose and test their visibility.

    A point is visible when it is in front of the camera, projects inside the image, its distance
    to the camera centre is within [0.8 min, 1.2 max] of its scale-invariance range and the
    viewing ray makes an angle with its mean viewing direction whose cosine is >= ``min_view_cos``.
    """
    p_world = np.asarray(p_world, dtype=float).reshape(-1, 3)
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    p_cam = p_world @ R.T + t
    z = p_cam[:, 2]
    safe_z = np.where(z > 1e-9, z, 1e-9)
    u = calibration.fx * p_cam[:, 0] / safe_z + calibration.cx
    v = calibration.fy * p_cam[:, 1] / safe_z + calibration.cy
    centre = -R.T @ t
    rays = p_world - centre
    dist = np.linalg.norm(rays, axis=1)
    view_cos = np.einsum("ij,ij->i", rays, normals) / np.maximum(dist, 1e-12)
    visible = (
        (z > 0)
        & (u >= 0)
        & (u < calibration.width)
        & (v >= 0)
        & (v < calibration.height)
        & (dist >= 0.8 * min_distance_m)
        & (dist <= 1.2 * max_distance_m)
        & (view_cos >= min_view_cos)
    )
    right_u = u - calibration.bf / safe_z if calibration.baseline_m is not None else np.full_like(u, np.nan)
    level = predict_scale_level(dist, max_distance_m, scale_factor, n_levels)
    return FrustumProjection(visible, np.column_stack([u, v]), right_u, view_cos, level)
