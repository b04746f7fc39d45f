"""Map points as the frontend uses them: frustum projection, and ``MapPoint`` for one point at a time.

The per-point rules (representative descriptor, normal, scale range) are shared with the backend
in ``zenslam.map_point_rules``; the frontend's local map stores points as arrays (``local_map.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.map_point_rules import (
    mean_viewing_direction,
    predict_scale_level,
    radius_by_viewing_cos,
    representative_descriptor,
    representative_descriptors,
    scale_invariance_range,
)

__all__ = [
    "FrustumProjection",
    "MapPoint",
    "mean_viewing_direction",
    "predict_scale_level",
    "project_in_frustum",
    "radius_by_viewing_cos",
    "representative_descriptor",
    "representative_descriptors",
    "scale_invariance_range",
]


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


@dataclass(eq=False)
class MapPoint:
    """One 3D point of the map, in the world frame, with its keyframe observations.

    ``observations`` maps keyframe id -> keypoint index in that keyframe. ``n_visible`` counts the
    frames whose frustum held the point, ``n_found`` those where it was matched and kept as an
    inlier; their ratio is ORB-SLAM's found ratio used to cull points.
    """

    id: int
    p_world: np.ndarray  # (3,) metres, world frame
    descriptor: np.ndarray  # (32,) uint8, the representative one
    normal: np.ndarray = field(default_factory=lambda: np.zeros(3))  # mean viewing direction
    min_distance_m: float = 0.0
    max_distance_m: float = math.inf
    reference_keyframe_id: int = -1
    observations: dict[int, int] = field(default_factory=dict)
    n_visible: int = 1
    n_found: int = 1

    def add_observation(self, keyframe_id: int, keypoint_index: int) -> None:
        """Record that keypoint ``keypoint_index`` of keyframe ``keyframe_id`` sees this point."""
        if not self.observations:
            self.reference_keyframe_id = keyframe_id
        self.observations[keyframe_id] = keypoint_index

    def found_ratio(self) -> float:
        """Frames where the point was found / frames where it should have been visible."""
        return self.n_found / max(self.n_visible, 1)

    def update_descriptor(self, observed_descriptors: np.ndarray) -> None:
        """Pick the representative of the descriptors (K, 32) observed in the keyframes."""
        self.descriptor = representative_descriptor(observed_descriptors)

    def update_normal_and_depth(
        self,
        centres_world: np.ndarray,
        reference_centre_world: np.ndarray,
        reference_level: int,
        scale_factor: float,
        n_levels: int,
    ) -> None:
        """Refresh the mean viewing direction from the observing camera centres (K, 3) and the
        scale-invariance distance range from the reference keyframe's centre and keypoint level."""
        self.normal = mean_viewing_direction(self.p_world, centres_world)
        distance = float(np.linalg.norm(np.asarray(self.p_world) - np.asarray(reference_centre_world)))
        lo, hi = scale_invariance_range(distance, reference_level, scale_factor, n_levels)
        self.min_distance_m, self.max_distance_m = float(lo), float(hi)

    def predict_scale(self, distance_m: float, scale_factor: float, n_levels: int) -> int:
        """Pyramid level at which the point should be detected from ``distance_m`` metres."""
        return int(predict_scale_level(distance_m, self.max_distance_m, scale_factor, n_levels))

    def in_distance_range(self, distance_m: float) -> bool:
        """ORB-SLAM's frustum distance test with its 0.8 / 1.2 margins on the invariance range."""
        return 0.8 * self.min_distance_m <= distance_m <= 1.2 * self.max_distance_m


__all__ = [
    "MapPoint",
    "mean_viewing_direction",
    "predict_scale_level",
    "project_in_frustum",
    "FrustumProjection",
    "radius_by_viewing_cos",
    "representative_descriptor",
    "representative_descriptors",
    "scale_invariance_range",
]
