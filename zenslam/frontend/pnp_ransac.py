"""A camera pose from 3D-2D matches by RANSAC over EPnP minimal sets (ORB-SLAM2's ``PnPsolver``).

Each hypothesis is EPnP on 4 matches drawn by a seeded generator, scored by the reprojection
error of every match against its own threshold (ORB-SLAM: chi-square 5.991 times the variance of
the keypoint's pyramid level), so a match found on a coarse level is allowed a larger error. As in
ORB-SLAM, the first hypothesis with enough inliers is refined by EPnP on all of its inliers and
accepted when the refined pose keeps enough. The generator is seeded per call, so the same
matches always give the same pose, whatever ran before.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.errors import ConfigError

logger = logging.getLogger(__name__)

_MIN_SET = 4  # EPnP's minimal set


@dataclass(frozen=True)
class PnpRansacConfig:
    """RANSAC settings (ORB-SLAM2's relocalisation: ``SetRansacParameters(0.99, 10, 300, 4, 0.5, 5.991)``)."""

    probability: float = 0.99  # wanted probability of drawing one all-inlier minimal set
    min_inliers: int = 10  # inliers a pose needs, at least (count)
    inlier_ratio: float = 0.5  # expected inlier fraction: also a pose needs this fraction of the matches
    max_iterations: int = 300  # hypotheses drawn, at most (count)
    chi2: float = 5.991  # squared reprojection error / level variance below which a match is an inlier (2 dof, 95%)
    seed: int = 0  # seed of the minimal-set draws

    def __post_init__(self) -> None:
        problems = []
        if not 0.0 < self.probability < 1.0:
            problems.append(f"probability={self.probability} must be in (0, 1)")
        if not 0.0 < self.inlier_ratio <= 1.0:
            problems.append(f"inlier_ratio={self.inlier_ratio} must be in (0, 1]")
        if self.max_iterations < 1 or self.min_inliers < _MIN_SET:
            problems.append(f"max_iterations={self.max_iterations} must be >= 1 and min_inliers={self.min_inliers} >= {_MIN_SET}")
        if problems:
            raise ConfigError("invalid relocalisation RANSAC configuration: " + "; ".join(problems))


@dataclass(frozen=True)
class PnpResult:
    """The pose RANSAC found and which matches agree with it."""

    T_cam_world: np.ndarray  # (4, 4) maps world points into the camera frame
    inliers: np.ndarray  # (N,) bool
    iterations: int  # hypotheses drawn


def pnp_ransac(
    p_world: np.ndarray,
    px: np.ndarray,
    level_sigma2: np.ndarray,
    calibration: PinholeCalibration,
    config: PnpRansacConfig | None = None,
) -> PnpResult | None:
    """The camera pose of N matches of world points ``p_world`` (N, 3) metres to level-0 pixels
    ``px`` (N, 2), whose keypoints have position variances ``level_sigma2`` (N,) px^2; None when no
    hypothesis gathers ``max(min_inliers, inlier_ratio * N)`` inliers."""
    config = config or PnpRansacConfig()
    p_world = np.ascontiguousarray(p_world, dtype=np.float64).reshape(-1, 3)
    px = np.ascontiguousarray(px, dtype=np.float64).reshape(-1, 2)
    n = len(p_world)
    needed = max(config.min_inliers, int(round(config.inlier_ratio * n)))
    if n < max(_MIN_SET, needed):
        return None
    th2 = config.chi2 * np.asarray(level_sigma2, dtype=np.float64).reshape(n)
    K = calibration.K
    rng = np.random.default_rng(config.seed)
    for iteration in range(1, _iterations(config) + 1):
        sample = rng.choice(n, _MIN_SET, replace=False)
        T = _epnp(p_world[sample], px[sample], K)
        if T is None:
            continue
        inliers = _inliers(T, p_world, px, th2, calibration)
        if np.count_nonzero(inliers) < needed:
            continue
        refined = _epnp(p_world[inliers], px[inliers], K)
        if refined is None:
            continue
        refined_inliers = _inliers(refined, p_world, px, th2, calibration)
        if np.count_nonzero(refined_inliers) >= needed:
            return PnpResult(refined, refined_inliers, iteration)
    return None


def _iterations(config: PnpRansacConfig) -> int:
    """Hypotheses to draw for ``probability`` at the expected inlier ratio (ORB-SLAM's formula), capped."""
    if config.inlier_ratio >= 1.0:
        return 1
    n = math.log(1.0 - config.probability) / math.log(1.0 - config.inlier_ratio**_MIN_SET)
    return max(1, min(config.max_iterations, int(math.ceil(n))))


def _epnp(p_world: np.ndarray, px: np.ndarray, K: np.ndarray) -> np.ndarray | None:
    """T_cam_world (4, 4) by EPnP from >= 4 matches, or None when OpenCV finds no solution."""
    try:
        ok, rvec, tvec = cv2.solvePnP(p_world, px, K, None, flags=cv2.SOLVEPNP_EPNP)
    except cv2.error:  # degenerate sets (collinear points) make OpenCV's EPnP throw
        return None
    if not ok or not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
        return None
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.reshape(3)
    return T


def _inliers(T: np.ndarray, p_world: np.ndarray, px: np.ndarray, th2: np.ndarray, calibration: PinholeCalibration) -> np.ndarray:
    """(N,) bool: in front of the camera and reprojected within each match's threshold."""
    p_cam = p_world @ T[:3, :3].T + T[:3, 3]
    z = p_cam[:, 2]
    safe_z = np.where(z > 1e-9, z, 1e-9)
    du = calibration.fx * p_cam[:, 0] / safe_z + calibration.cx - px[:, 0]
    dv = calibration.fy * p_cam[:, 1] / safe_z + calibration.cy - px[:, 1]
    return (z > 1e-9) & (du * du + dv * dv < th2)
