"""What local bundle adjustment takes and gives: its settings, the window problem and the result.

Plain numpy, apart from the solver (``local_ba``), so that configuration and local mapping can
name them without loading gtsam.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.errors import ZenslamError


@dataclass(frozen=True)
class LocalBAConfig:
    """Settings of local bundle adjustment (defaults are ORB-SLAM2's schedule and thresholds)."""

    # Levenberg-Marquardt on the whole window. schur_lm: each step solved on the reduced camera
    # system, the landmarks eliminated by their Schur complement in numpy (``schur_ba``); batch_lm:
    # gtsam's LevenbergMarquardtOptimizer on the window's factor graph (``local_ba``). The same
    # problem, steps and stopping rules, so the same optimum; schur_lm is the faster one on local
    # windows (it skips gtsam's per-landmark factor machinery; benchmarks/local_ba.md).
    method: Literal["schur_lm", "batch_lm"] = "schur_lm"
    # batch_lm's gtsam settings:
    linear_solver: Literal["sequential_cholesky", "multifrontal_cholesky", "multifrontal_qr"] = "sequential_cholesky"
    # Elimination ordering: every landmark, then every pose (the Schur-complement order of BA
    # solvers), or gtsam's COLAMD / METIS. COLAMD interleaves poses in larger windows
    # (benchmarks/local_ba.md).
    ordering: Literal["landmarks_first", "colamd", "metis"] = "landmarks_first"
    robust_iterations: int = 5  # first pass, Huber kernel on every observation (count)
    # Second pass, without outliers and without the kernel (count). ORB-SLAM runs 10; after the
    # robust pass one Levenberg-Marquardt step is what it takes: a second one mostly confirmed
    # convergence, at the cost of a solve (benchmarks/local_ba.md).
    refine_iterations: int = 1
    two_passes: bool = True  # False: the robust pass only, then the final classification
    # Huber thresholds on whitened residual norms (sqrt of the 95% chi2 values, unitless).
    huber_mono: float = math.sqrt(5.991)  # (u, v) residuals, 2 dof
    huber_stereo: float = math.sqrt(7.815)  # (u, v, u_right) residuals, 3 dof
    # Outlier thresholds on information-weighted squared errors (px^2 / sigma^2, unitless).
    chi2_mono: float = 5.991  # 95% of chi2 with 2 dof
    chi2_stereo: float = 7.815  # 95% of chi2 with 3 dof
    min_depth_m: float = 1e-3  # a point nearer than this along a camera's optical axis is behind it (m)
    # A pass stops early when the error drops by less than this fraction in one iteration: the
    # iterations are caps; past a 1e-3 relative decrease the estimate moves by far less than its noise.
    relative_error_tolerance: float = 1e-3
    absolute_error_tolerance: float = 1e-5  # ... or by less than this (whitened squared error, unitless)
    # Levenberg-Marquardt damping lambda * I (unitless). Every rejected step costs a full
    # elimination, and with little damping the weak depth of far monocular points gets steps
    # rejected often (from gtsam's 1e-5, most first steps of a robust pass): a floor of 1e-2 trades
    # a slightly higher final error for far fewer rejected steps (benchmarks/local_ba.py).
    lambda_initial: float = 1e-2  # at a pass's start
    lambda_lower_bound: float = 1e-2  # never damp less than this
    max_retries: int = 8  # solver failures repaired by dropping the landmark gtsam names (count)


@dataclass(frozen=True)
class BAProblem:
    """A local window: poses, points and observations; observation rows index keyframes and points."""

    calibration: PinholeCalibration  # rectified left camera; baseline_m needed for stereo rows
    keyframe_ids: np.ndarray  # (K,) int64, unique
    T_world_cam: np.ndarray  # (K, 4, 4) initial poses, map camera coordinates to world (metres)
    fixed: np.ndarray  # (K,) bool, True: the pose is held exactly
    point_ids: np.ndarray  # (P,) int64, unique
    p_world: np.ndarray  # (P, 3) initial positions in the world frame (metres)
    obs_keyframe: np.ndarray  # (O,) int, row into keyframe_ids
    obs_point: np.ndarray  # (O,) int, row into point_ids
    obs_px: np.ndarray  # (O, 2) left keypoint (u, v) in level-0 pixels
    obs_right_u: np.ndarray  # (O,) right-image u in pixels; NaN for a monocular observation
    obs_inv_sigma2: np.ndarray  # (O,) 1 / scale_factor**(2 * level) (1/px^2)
    # (O,) multiplier of the right-image u's sigma (>= 1; far stereo observations get a weaker
    # disparity); None = 1 everywhere.
    obs_right_sigma_scale: np.ndarray | None = None
    # (O,) px: sigma of the disparity u - u_right where the right u is RGB-D's virtual one,
    # u - bf / depth: it shares the keypoint's error and adds the depth sensor's, independent of
    # the pyramid level; 0 (or None) = the right u is an image measurement of its own (stereo).
    obs_disparity_sigma: np.ndarray | None = None

    def __post_init__(self) -> None:
        # Coerce to the documented dtypes (no copy when they already match), then check consistency.
        dtypes = {
            "keyframe_ids": np.int64, "T_world_cam": np.float64, "fixed": bool, "point_ids": np.int64,
            "p_world": np.float64, "obs_keyframe": np.intp, "obs_point": np.intp, "obs_px": np.float64,
            "obs_right_u": np.float64, "obs_inv_sigma2": np.float64,
        }  # fmt: skip
        for name in ("obs_right_sigma_scale", "obs_disparity_sigma"):
            if getattr(self, name) is not None:
                dtypes[name] = np.float64
        for name, dtype in dtypes.items():
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=dtype))
        _check_problem(self)


@dataclass(frozen=True)
class BAResult:
    """The optimised window and the classification of every observation."""

    T_world_cam: np.ndarray  # (K, 4, 4); fixed keyframes are the input poses, bit for bit
    p_world: np.ndarray  # (P, 3) metres; input position for held and removed points
    inlier_obs: np.ndarray  # (O,) bool, classification at the final estimate
    # (R,) int64: points left without any inlier observation (behind the cameras, every observation
    # an outlier, dropped as degenerate by gtsam, non-finite, or given no observation); local
    # mapping should erase them.
    removed_point_ids: np.ndarray
    stats: dict = field(default_factory=dict)  # iterations, initial/final_error, time_ms, n_outliers, ...


def _check_problem(problem: BAProblem) -> None:
    """Raise ZenslamError naming every mis-shaped or inconsistent array of ``problem``."""
    K, P, O = len(problem.keyframe_ids), len(problem.point_ids), len(problem.obs_keyframe)
    expected = {
        "keyframe_ids": (K,), "T_world_cam": (K, 4, 4), "fixed": (K,), "point_ids": (P,), "p_world": (P, 3),
        "obs_keyframe": (O,), "obs_point": (O,), "obs_px": (O, 2), "obs_right_u": (O,), "obs_inv_sigma2": (O,),
    }  # fmt: skip
    for name in ("obs_right_sigma_scale", "obs_disparity_sigma"):
        if getattr(problem, name) is not None:
            expected[name] = (O,)
    problems = [
        f"{name} has shape {np.shape(getattr(problem, name))}, expected {shape}"
        for name, shape in expected.items()
        if np.shape(getattr(problem, name)) != shape
    ]
    if not problems:
        if len(np.unique(problem.keyframe_ids)) != K or len(np.unique(problem.point_ids)) != P:
            problems.append("keyframe_ids and point_ids must be unique")
        if O and not (0 <= np.min(problem.obs_keyframe) and np.max(problem.obs_keyframe) < K):
            problems.append(f"obs_keyframe must index the {K} keyframes")
        if O and not (0 <= np.min(problem.obs_point) and np.max(problem.obs_point) < P):
            problems.append(f"obs_point must index the {P} points")
        if not np.isfinite(problem.T_world_cam).all():
            bad = problem.keyframe_ids[~np.isfinite(problem.T_world_cam).all(axis=(1, 2))]
            problems.append(f"T_world_cam of keyframes {bad.tolist()} holds non-finite values")
    if problems:
        raise ZenslamError("invalid local BA problem: " + "; ".join(problems) + "; fix the window built by local mapping")


def constrained_points(problem: BAProblem, stereo: np.ndarray, active: np.ndarray) -> np.ndarray:
    """(P,) bool: the points a BA pass can optimise, with one active stereo observation (depth from
    disparity) or active observations from two distinct keyframes; ``stereo`` and ``active`` are (O,)."""
    n_points, n_keyframes = len(problem.point_ids), len(problem.keyframe_ids)
    stereo_count = np.bincount(problem.obs_point[active & stereo], minlength=n_points)
    # distinct (point, keyframe) pairs as one integer each: a 1-D unique is far cheaper than axis=0
    pairs = np.unique(problem.obs_point[active].astype(np.int64) * n_keyframes + problem.obs_keyframe[active])
    view_count = np.bincount(pairs // n_keyframes, minlength=n_points)
    return (stereo_count > 0) | (view_count >= 2)


def ba_stats(
    config: LocalBAConfig, *, iterations: int, initial_error: float, final_error: float, seconds: float,
    inlier_obs: np.ndarray, removed_point_ids: np.ndarray, n_dropped_points: int, passes: int, retries: int,
    failure: str | None,
) -> dict:
    """``BAResult.stats``, the same keys whichever solver ran."""
    return {
        "method": config.method,
        "iterations": iterations,
        "initial_error": initial_error,
        "final_error": final_error,
        "time_ms": 1e3 * seconds,
        "n_observations": int(len(inlier_obs)),
        "n_outliers": int((~inlier_obs).sum()),
        "n_removed_points": int(len(removed_point_ids)),
        "n_dropped_points": int(n_dropped_points),
        "passes": passes,
        "retries": retries,
        "failure": failure,
    }
