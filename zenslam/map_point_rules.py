"""ORB-SLAM's per-map-point rules as vectorised functions, shared by the frontend and the backend.

Representative descriptor, scale-invariance distance range, predicted pyramid level, mean
viewing direction, the frustum test (``isInFrustum``) and the search-window factor by viewing
angle (Mur-Artal et al., ORB-SLAM).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration


def representative_descriptor(descriptors: np.ndarray) -> np.ndarray:
    """The descriptor (32,) uint8 with the least median Hamming distance to the others.

    ORB-SLAM's ``ComputeDistinctiveDescriptors``: the median of a row of K sorted distances
    (itself included, at 0) is element ``(K - 1) // 2``; ties go to the first descriptor.
    """
    descriptors = np.asarray(descriptors, dtype=np.uint8)
    if descriptors.ndim != 2 or descriptors.shape[0] == 0:
        raise ValueError(f"need a non-empty (K, 32) descriptor array, got shape {descriptors.shape}")
    return representative_descriptors(descriptors[None])[0]


def representative_descriptors(groups: np.ndarray, counts: np.ndarray | None = None) -> np.ndarray:
    """Representative descriptors (P, 32) of P groups of K descriptors each, ``groups`` (P, K, 32).

    With ``counts`` (P,), group p holds only its first ``counts[p]`` descriptors (1..K); the rest is
    padding, ignored."""
    groups = np.ascontiguousarray(groups, dtype=np.uint8)
    n_groups, k = groups.shape[:2]
    counts = np.full(n_groups, k, np.int64) if counts is None else np.asarray(counts, dtype=np.int64)
    offsets = representative_offsets(groups.reshape(-1, 32), np.arange(n_groups, dtype=np.int64) * k, counts)
    return groups[np.arange(n_groups), offsets]


def representative_offsets(descriptors: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The rule of ``representative_descriptors`` on runs: point p's descriptors are rows
    ``starts[p]:starts[p] + counts[p]`` (counts >= 1) of ``descriptors`` (O, 32) uint8; returns the
    (P,) offset of each point's representative within its run."""
    # compiled (numba: ~60 MB, most of a second at a process's start): only a process that needs it loads it
    from zenslam.compiled import kernel_array
    from zenslam.descriptor_words import words
    from zenslam.representative_descriptor import representative_offsets as compiled

    return compiled(
        kernel_array(words(descriptors), np.uint64), kernel_array(starts, np.int64), kernel_array(counts, np.int64)
    )


def scale_invariance_range(
    distance_m: np.ndarray | float, level: np.ndarray | int, scale_factor: float, n_levels: int
) -> tuple[np.ndarray, np.ndarray]:
    """Distances (metres) over which a point seen at ``distance_m`` on pyramid ``level`` stays detectable.

    max = distance * scale_factor**level (seen on level 0 from there), min = max /
    scale_factor**(n_levels - 1) (seen on the top level); ORB-SLAM's ``UpdateNormalAndDepth``.
    """
    distance_m = np.asarray(distance_m, dtype=float)
    level = np.asarray(level)
    max_m = distance_m * scale_factor ** level.astype(float)
    min_m = max_m / scale_factor ** (n_levels - 1)
    return min_m, max_m


def predict_scale_level(
    distance_m: np.ndarray | float, max_distance_m: np.ndarray | float, scale_factor: float, n_levels: int
) -> np.ndarray:
    """Pyramid level (int) at which a point with ``max_distance_m`` should appear from ``distance_m``.

    ORB-SLAM's ``PredictScale``: ceil(log(max / distance) / log(scale_factor)), clamped to
    [0, n_levels - 1].
    """
    distance_m = np.maximum(np.asarray(distance_m, dtype=float), 1e-12)
    ratio = np.asarray(max_distance_m, dtype=float) / distance_m
    with np.errstate(divide="ignore"):
        # The tolerance keeps exact level ratios (log 1.44 / log 1.2 = 2.0000000001) on their level.
        level = np.ceil(np.log(ratio) / math.log(scale_factor) - 1e-9)
    return np.clip(level, 0, n_levels - 1).astype(np.int64)


def mean_viewing_direction(p_world: np.ndarray, centres_world: np.ndarray) -> np.ndarray:
    """Mean of the unit vectors from the camera centres (K, 3) to the point (3,), world frame.

    Not renormalised, as in ORB-SLAM (the viewing-angle test divides by the point distance only).
    """
    p_world = np.asarray(p_world, dtype=float)
    return mean_viewing_directions(p_world[None], np.asarray(centres_world, dtype=float)[None])[0]


def mean_viewing_directions(p_world: np.ndarray, centres_world: np.ndarray, counts: np.ndarray | None = None) -> np.ndarray:
    """``mean_viewing_direction`` of P points (P, 3), each seen from K camera centres (P, K, 3) -> (P, 3).

    With ``counts`` (P,), point p is seen from its first ``counts[p]`` centres (1..K) only; the rest
    is padding, ignored."""
    centres_world = np.ascontiguousarray(centres_world, dtype=float)
    n_points, k = centres_world.shape[:2]
    counts = np.full(n_points, k, np.int64) if counts is None else np.asarray(counts, dtype=np.int64)
    return mean_viewing_directions_of_runs(p_world, centres_world.reshape(-1, 3), np.arange(n_points, dtype=np.int64) * k, counts)


def mean_viewing_directions_of_runs(p_world: np.ndarray, centres_world: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """``mean_viewing_direction`` of P points (P, 3), point p seen from the centres
    ``starts[p]:starts[p] + counts[p]`` (counts >= 1) of ``centres_world`` (O, 3) -> (P, 3)."""
    # compiled (numba: ~60 MB, most of a second at a process's start): only a process that needs it loads it
    from zenslam.compiled import kernel_array
    from zenslam.viewing_direction import mean_rays

    return mean_rays(
        kernel_array(p_world, np.float64), kernel_array(centres_world, np.float64), kernel_array(starts, np.int64),
        kernel_array(counts, np.int64),
    )  # fmt: skip


@dataclass(frozen=True)
class FrustumVerdict:
    """ORB-SLAM's ``isInFrustum`` verdict on M projected points, with what it measured on the way."""

    visible: np.ndarray  # (M,) bool: in front, inside the image, within the distance range, viewing angle ok
    view_cos: np.ndarray  # (M,) cosine between the viewing ray and the point's mean viewing direction
    distance_m: np.ndarray  # (M,) distance to the camera centre, metres
    level: np.ndarray  # (M,) int64 predicted pyramid level


def frustum_verdict(
    p_world: np.ndarray,
    centre_world: np.ndarray,
    depth_m: np.ndarray,
    px: np.ndarray,
    normals: np.ndarray,
    min_distance_m: np.ndarray,
    max_distance_m: np.ndarray,
    calibration: PinholeCalibration,
    scale_factor: float,
    n_levels: int,
    min_view_cos: float = 0.5,
) -> FrustumVerdict:
    """The frustum test of points (M, 3, world, metres) already projected by the caller: their depth
    ``depth_m`` (M,) and pixels ``px`` (M, 2) in the camera centred at ``centre_world`` (3,).

    A point is visible when it is in front of the camera, projects inside the image, its distance
    to the camera centre is within [0.8 min, 1.2 max] of its scale-invariance range and the
    viewing ray makes an angle with its mean viewing direction ``normals`` (M, 3) whose cosine is
    >= ``min_view_cos``. Each stage projects with its own pose representation; the verdict is this one.
    """
    rays = p_world - centre_world
    dist = np.linalg.norm(rays, axis=1)
    view_cos = np.einsum("ij,ij->i", rays, normals) / np.maximum(dist, 1e-12)
    u, v = px[:, 0], px[:, 1]
    visible = (
        (depth_m > 0)
        & (u >= 0) & (u < calibration.width) & (v >= 0) & (v < calibration.height)
        & (dist >= 0.8 * min_distance_m) & (dist <= 1.2 * max_distance_m)
        & (view_cos >= min_view_cos)
    )  # fmt: skip
    level = predict_scale_level(dist, max_distance_m, scale_factor, n_levels)
    return FrustumVerdict(visible, view_cos, dist, level)


def radius_by_viewing_cos(view_cos: np.ndarray) -> np.ndarray:
    """ORB-SLAM's search-window factor: 2.5 when seen almost head-on (cos > 0.998), else 4.0."""
    return np.where(np.asarray(view_cos) > 0.998, 2.5, 4.0)
