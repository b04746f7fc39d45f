"""ORB-SLAM's ``isInFrustum`` for many map points at once: the frontend's projection and the verdicts.

The verdict (distance margins, viewing-angle gate, scale prediction) is the rule shared with the
backend, ``zenslam.map_point_rules.frustum_verdict``; the frontend's local map stores points as
arrays (``local_map.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.map_point_rules import frustum_verdict


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
    """Project points (M, 3, world, metres) with the world -> camera pose and test their visibility
    (``map_point_rules.frustum_verdict``: in front, inside the image, within [0.8 min, 1.2 max] of
    the scale-invariance range, viewing cosine >= ``min_view_cos``)."""
    p_world = np.asarray(p_world, dtype=float).reshape(-1, 3)
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    p_cam = p_world @ R.T + t
    z = p_cam[:, 2]
    safe_z = np.where(z > 1e-9, z, 1e-9)
    u = calibration.fx * p_cam[:, 0] / safe_z + calibration.cx
    v = calibration.fy * p_cam[:, 1] / safe_z + calibration.cy
    px = np.column_stack([u, v])
    verdict = frustum_verdict(
        p_world, -R.T @ t, z, px, normals, min_distance_m, max_distance_m, calibration, scale_factor, n_levels, min_view_cos
    )
    right_u = u - calibration.bf / safe_z if calibration.baseline_m is not None else np.full_like(u, np.nan)
    return FrustumProjection(verdict.visible, px, right_u, verdict.view_cos, verdict.level)
