"""Pose-only optimisation: one camera pose from fixed map points, with ORB-SLAM2's outlier rounds.

Shared by the frontend (tracking, relocalisation, visual odometry: ``frontend.frame.optimize_frame_pose``)
and the backend (placing a keyframe whose local BA waits: ``backend.keyframe_placement``).

The camera pose ``T_cam_world`` maps world points into the camera frame (x right, y down,
z forward). Observations are level-0 pixels ``(u, v)`` and, for stereo / RGB-D keypoints, the
right-image coordinate ``u_right = u - bf / z``. This is ORB-SLAM2's ``Optimizer::PoseOptimization``
(robust rounds, chi-square outlier classification, kernel dropped in the last round) solved by
Levenberg-Marquardt on SE(3), its normal equations summed by a compiled loop over the observations
(``pose_normal_equations``): the same answers as gtsam factor graphs of the problem, in a fraction
of the time, because building and linearising per-observation factors from Python dominates a
single 6-dof solve (``benchmarks/pose_optimizer.py``, benchmarks/frontend.md).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.geometry import se3_exp

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class PoseOptimizerConfig:
    """Settings of pose-only optimisation (defaults are ORB-SLAM2's)."""

    rounds: int = 4  # outlier-classification rounds (count)
    iterations_per_round: int = 10  # Levenberg-Marquardt iterations per round (count)
    robust_rounds: int = 3  # leading rounds with the Huber kernel; later rounds are plain least squares (count)
    # Chi-square thresholds at 95% on information-weighted squared errors (px^2 / sigma^2, unitless);
    # the Huber threshold is their square root, as ORB-SLAM2.
    chi2_mono: float = 5.991  # (u, v) residuals, 2 dof
    chi2_stereo: float = 7.815  # (u, v, u_right) residuals, 3 dof
    min_observations: int = 3  # fewer usable correspondences: no optimisation, n_inliers 0 (count)
    min_observations_for_rounds: int = 10  # fewer correspondences: stop after one round, as ORB-SLAM2 (count)
    min_depth_m: float = 1e-3  # points nearer than this along the optical axis count as behind the camera (m)
    initial_damping: float = 1e-4  # Levenberg-Marquardt lambda, relative to diag(H), at a round's start (unitless)
    step_tolerance: float = 1e-9  # a round ends early when the update's norm is below this (rad and m mixed)


@dataclass(frozen=True)
class PoseResult:
    """The optimised pose and the classification of every observation."""

    T_cam_world: np.ndarray  # (4, 4) maps world points into the camera frame
    inliers: np.ndarray  # (N,) bool, classification after the last round
    n_inliers: int  # inliers.sum(); 0 when the pose could not be optimised
    chi2: np.ndarray  # (N,) information-weighted squared error at the final pose; inf behind the camera, nan unusable
    iterations: int  # Levenberg-Marquardt iterations over all rounds (count)
    rounds: int  # rounds run (count)


@dataclass(frozen=True)
class _Problem:
    """The fixed data of one optimisation, in the solver's stacked layout."""

    p_world: np.ndarray  # (N, 3)
    obs: np.ndarray  # (N, 3) u, v, u_right (0 for mono rows)
    row_mask: np.ndarray  # (N, 3) 1 where the residual row exists (u_right only for stereo)
    inv_sigma2: np.ndarray  # (N,)
    delta2: np.ndarray  # (N,) squared Huber threshold, = chi-square threshold of the observation's dof
    fx: float
    fy: float
    cx: float
    cy: float
    bf: float
    # (N, 3, 3) information of each observation's (u, v, u_right) residual, used instead of
    # inv_sigma2 when the points' own uncertainty is counted (``point_covariance``); None: inv_sigma2.
    information: np.ndarray | None = None

    def subset(self, rows: np.ndarray) -> _Problem:
        """The problem restricted to the observations selected by the boolean mask ``rows``."""
        return dataclasses.replace(
            self,
            p_world=self.p_world[rows],
            obs=self.obs[rows],
            row_mask=self.row_mask[rows],
            inv_sigma2=self.inv_sigma2[rows],
            delta2=self.delta2[rows],
            information=None if self.information is None else self.information[rows],
        )


def optimize_pose(
    T_cam_world_init: np.ndarray,
    p_world: np.ndarray,
    obs_px: np.ndarray,
    obs_right_u: np.ndarray,
    inv_sigma2: np.ndarray,
    calibration: PinholeCalibration,
    config: PoseOptimizerConfig,
    point_covariance: np.ndarray | None = None,
) -> PoseResult:
    """Optimise the camera pose from fixed world points and their observations.

    T_cam_world_init: (4, 4) initial pose, maps world points (metres) into the camera frame.
    p_world: (N, 3) map points in the world frame (metres).
    obs_px: (N, 2) observed keypoint (u, v) in level-0 pixels.
    obs_right_u: (N,) observed right-image u in pixels; NaN or negative for a mono observation.
    inv_sigma2: (N,) information of the observation, 1 / scale_factor**(2 * level) (1/px^2).
    Rows with a non-finite point or pixel are never used and never inliers.
    point_covariance: (N, 3, 3) covariance of each point's position (m^2, world frame), zeros for a
    point taken as exact; None: every point exact. An observation's residual covariance is then its
    pixel noise plus the point's covariance projected into the image (at the initial pose), and its
    information the inverse: a point known only roughly along some direction pulls the pose less
    along it, and its chi-square (the outlier test) allows for it.

    Each round runs Levenberg-Marquardt on the current inliers (all usable observations in the
    first round), then re-classifies *every* observation by its chi-square at the new pose, so a
    point rejected earlier can come back, as in ORB-SLAM2. Unlike ORB-SLAM2, a round starts from
    the previous round's estimate rather than the initial pose. Fewer than
    ``config.min_observations`` usable rows is an expected outcome: the initial pose is returned
    with ``n_inliers == 0``.
    """
    T_init = np.asarray(T_cam_world_init, dtype=float)
    p_world, obs_px, obs_right_u, inv_sigma2 = _check_shapes(T_init, p_world, obs_px, obs_right_u, inv_sigma2)
    n = len(p_world)
    usable = (
        np.isfinite(p_world).all(axis=1)
        & np.isfinite(obs_px).all(axis=1)
        & np.isfinite(inv_sigma2)
        & (inv_sigma2 > 0)
    )
    if int(usable.sum()) < config.min_observations:
        logger.debug("pose optimisation skipped: %d usable observations of %d", int(usable.sum()), n)
        chi2 = np.full(n, np.nan)
        return PoseResult(T_init.copy(), np.zeros(n, dtype=bool), 0, chi2, 0, 0)

    problem = _make_problem(p_world, obs_px, obs_right_u, inv_sigma2, usable, calibration, config)
    if point_covariance is not None:
        problem = _with_point_covariance(problem, T_init, _checked_covariance(point_covariance, n, usable))
    T = T_init.copy()
    active = usable.copy()
    iterations = 0
    rounds_run = 0
    for round_index in range(config.rounds):
        robust = round_index < config.robust_rounds
        if int(active.sum()) >= config.min_observations:
            T, its = _solve_round(T, problem.subset(active), robust, config)
            iterations += its
        rounds_run += 1
        chi2, in_front = _chi2(T, problem, config.min_depth_m)
        active = usable & in_front & (chi2 <= problem.delta2)
        if int(usable.sum()) < config.min_observations_for_rounds:
            break
    chi2 = np.where(usable, chi2, np.nan)
    n_inliers = int(active.sum())
    logger.debug("pose optimisation: %d/%d inliers after %d iterations", n_inliers, n, iterations)
    return PoseResult(T, active, n_inliers, chi2, iterations, rounds_run)


def position_sigma(
    T_cam_world: np.ndarray,
    p_world: np.ndarray,
    obs_px: np.ndarray,
    obs_right_u: np.ndarray,
    inv_sigma2: np.ndarray,
    calibration: PinholeCalibration,
) -> float:
    """Largest standard deviation (metres) of the camera centre of the pose ``T_cam_world`` given the
    observations (``optimize_pose``'s arguments, inliers only), with the rotation marginalised out.

    From the observations' information at that pose (the Gauss-Newton H = J^T W J, whose inverse is
    the pose's covariance under the pixel noise the levels' sigmas state). The map points are taken as
    exact, so it is a lower bound; what it shows is how well the observations' geometry pins the
    camera down: points far away and on one plane trade sideways motion for rotation, and the sigma
    along that direction grows. Infinite when the observations do not fix the pose.
    """
    H = pose_information(T_cam_world, p_world, obs_px, obs_right_u, inv_sigma2, calibration)
    try:
        covariance = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return math.inf
    # T <- exp(xi) T moves the centre by -R^T upsilon to first order: its covariance is upsilon's
    # block rotated, with the same eigenvalues.
    largest = float(np.linalg.eigvalsh(covariance[3:, 3:])[-1])
    return math.sqrt(largest) if largest > 0 else math.inf


def pose_information(
    T_cam_world: np.ndarray,
    p_world: np.ndarray,
    obs_px: np.ndarray,
    obs_right_u: np.ndarray,
    inv_sigma2: np.ndarray,
    calibration: PinholeCalibration,
    point_covariance: np.ndarray | None = None,
) -> np.ndarray:
    """(6, 6) information of the pose ``T_cam_world`` from the observations (``optimize_pose``'s
    arguments, inliers only): the Gauss-Newton H = J^T W J at that pose, without a kernel, on the
    left perturbation T <- exp(xi) T with xi = (omega rad, upsilon m), as ``optimize_pose`` steps.
    ``point_covariance`` weighs the observations as ``optimize_pose`` does. All zeros (no
    information) with fewer than 3 usable observations."""
    T = np.asarray(T_cam_world, dtype=float)
    p_world, obs_px, obs_right_u, inv_sigma2 = _check_shapes(T, p_world, obs_px, obs_right_u, inv_sigma2)
    usable = np.isfinite(p_world).all(axis=1) & np.isfinite(obs_px).all(axis=1) & (inv_sigma2 > 0)
    if int(usable.sum()) < 3:
        return np.zeros((6, 6))
    problem = _make_problem(p_world, obs_px, obs_right_u, inv_sigma2, usable, calibration, PoseOptimizerConfig())
    if point_covariance is not None:
        problem = _with_point_covariance(problem, T, _checked_covariance(point_covariance, len(p_world), usable))
    _, H, _ = _linearize(T, problem.subset(usable), robust=False, min_depth_m=PoseOptimizerConfig().min_depth_m)
    return H


def _check_shapes(T, p_world, obs_px, obs_right_u, inv_sigma2):
    """The inputs as float arrays of consistent shapes; ValueError names the offending argument."""
    if T.shape != (4, 4):
        raise ValueError(f"T_cam_world_init must be a 4x4 transform, got shape {T.shape}")
    n = len(p_world)
    expected = {"p_world": (n, 3), "obs_px": (n, 2), "obs_right_u": (n,), "inv_sigma2": (n,)}
    given = {"p_world": p_world, "obs_px": obs_px, "obs_right_u": obs_right_u, "inv_sigma2": inv_sigma2}
    arrays = []
    for name, shape in expected.items():
        array = np.asarray(given[name], dtype=float)
        if array.size == 0 and n == 0:
            array = array.reshape(shape)
        if array.shape != shape:
            raise ValueError(f"{name} has shape {array.shape}, expected {shape} for {n} observations")
        arrays.append(array)
    return tuple(arrays)


def _make_problem(p_world, obs_px, obs_right_u, inv_sigma2, usable, calibration, config) -> _Problem:
    stereo = usable & np.isfinite(obs_right_u) & (obs_right_u >= 0)
    # A stereo observation needs bf; calibration.bf raises a CalibrationError for a mono camera.
    bf = calibration.bf if stereo.any() else 0.0
    obs = np.zeros((len(p_world), 3))
    obs[:, :2] = np.where(usable[:, None], obs_px, 0.0)
    obs[:, 2] = np.where(stereo, obs_right_u, 0.0)
    row_mask = np.ones((len(p_world), 3))
    row_mask[:, 2] = stereo
    return _Problem(
        p_world=np.where(usable[:, None], p_world, 0.0),
        obs=obs,
        row_mask=row_mask,
        inv_sigma2=np.where(usable, inv_sigma2, 0.0),
        delta2=np.where(stereo, config.chi2_stereo, config.chi2_mono),
        fx=calibration.fx,
        fy=calibration.fy,
        cx=calibration.cx,
        cy=calibration.cy,
        bf=bf,
    )


def _checked_covariance(point_covariance: np.ndarray, n: int, usable: np.ndarray) -> np.ndarray:
    covariance = np.asarray(point_covariance, dtype=float)
    if covariance.shape != (n, 3, 3):
        raise ValueError(f"point_covariance has shape {covariance.shape}, expected {(n, 3, 3)} for {n} observations")
    return np.where(usable[:, None, None] & np.isfinite(covariance), covariance, 0.0)


def _with_point_covariance(problem: _Problem, T: np.ndarray, covariance: np.ndarray) -> _Problem:
    """``problem`` with each observation's information inv(sigma^2 I + J C J^T) on its present rows,
    J = d(u, v, u_right)/d(p_world) at pose T, C the point's covariance; unchanged when every C is 0."""
    if not covariance.any():
        return problem
    J = point_jacobian(T, problem.p_world, problem.fx, problem.fy, problem.bf)
    present = problem.row_mask[:, :, None] * problem.row_mask[:, None, :]
    sigma2 = 1.0 / np.where(problem.inv_sigma2 > 0, problem.inv_sigma2, 1.0)
    residual_cov = (J @ covariance @ J.transpose(0, 2, 1)) * present + sigma2[:, None, None] * np.eye(3)
    information = np.linalg.inv(residual_cov) * present  # absent rows are independent: inverting leaves them out
    information *= (problem.inv_sigma2 > 0)[:, None, None]
    return dataclasses.replace(problem, information=information)


def point_jacobian(T_cam_world: np.ndarray, p_world: np.ndarray, fx: float, fy: float, bf: float) -> np.ndarray:
    """(N, 3, 3) d(u, v, u_right)/d(p_world) of world points ``p_world`` (N, 3) seen by the camera
    ``T_cam_world`` (u_right = u - bf / z; its row is meaningless for a mono observation). Points
    nearer than 1 mm along the optical axis are taken at 1 mm."""
    p_cam = p_world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    x, y = p_cam[:, 0], p_cam[:, 1]
    inv_z = 1.0 / np.maximum(p_cam[:, 2], 1e-3)
    J = np.zeros((len(p_cam), 3, 3))
    J[:, 0, 0] = fx * inv_z
    J[:, 0, 2] = -fx * x * inv_z * inv_z
    J[:, 1, 1] = fy * inv_z
    J[:, 1, 2] = -fy * y * inv_z * inv_z
    J[:, 2, 0] = J[:, 0, 0]
    J[:, 2, 2] = J[:, 0, 2] + bf * inv_z * inv_z
    return J @ T_cam_world[:3, :3]


def _weighted_chi2(residual: np.ndarray, problem: _Problem) -> np.ndarray:
    """Per-observation r^T W r: W the information matrix, or inv_sigma2 I."""
    if problem.information is not None:
        return np.einsum("nk,nkl,nl->n", residual, problem.information, residual)
    return problem.inv_sigma2 * np.einsum("nk,nk->n", residual, residual)


def _project(T: np.ndarray, problem: _Problem) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points (N, 3) and residuals predicted - observed (N, 3), zero on absent rows."""
    p_cam = problem.p_world @ T[:3, :3].T + T[:3, 3]
    z = p_cam[:, 2]
    inv_z = 1.0 / np.where(np.abs(z) > 1e-12, z, 1e-12)
    pred = np.empty_like(p_cam)
    pred[:, 0] = problem.fx * p_cam[:, 0] * inv_z + problem.cx
    pred[:, 1] = problem.fy * p_cam[:, 1] * inv_z + problem.cy
    pred[:, 2] = pred[:, 0] - problem.bf * inv_z
    return p_cam, (pred - problem.obs) * problem.row_mask


def _chi2(T: np.ndarray, problem: _Problem, min_depth_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-observation chi-square (inf behind the camera) and the in-front mask at pose T."""
    p_cam, residual = _project(T, problem)
    in_front = p_cam[:, 2] > min_depth_m
    chi2 = _weighted_chi2(residual, problem)
    return np.where(in_front, chi2, np.inf), in_front


def _linearize(T: np.ndarray, problem: _Problem, robust: bool, min_depth_m: float):
    """Robust cost and normal equations (H, g) of the IRLS-weighted problem at T (``pose_normal_equations``)."""
    # Imported here: the compiled kernel loads numba (~60 MB), and the processes that only read a
    # PoseOptimizerConfig (the supervising run, the backend) do not optimise poses.
    from zenslam.pose_normal_equations import normal_equations

    information = problem.information if problem.information is not None else _NO_INFORMATION
    return normal_equations(
        T, problem.p_world, problem.obs, problem.row_mask, problem.inv_sigma2, problem.delta2, information,
        problem.fx, problem.fy, problem.cx, problem.cy, problem.bf, robust, min_depth_m,
    )


_NO_INFORMATION = np.zeros((0, 3, 3))  # ``normal_equations``: weigh by inv_sigma2 alone


def load_compiled_kernel() -> None:
    """Load the normal equations' compiled kernel from numba's cache (compile it, on a machine's first
    start): for a process to call at its start when a later first pose optimisation must not wait
    for it (numba's start and the load take most of a second)."""
    _linearize(np.eye(4), _Problem(*(np.ones((1, 3)),) * 3, np.ones(1), np.ones(1), 1.0, 1.0, 0.0, 0.0, 0.0), True, 1e-3)


def _solve_round(T, problem, robust, config) -> tuple[np.ndarray, int]:
    """Levenberg-Marquardt with IRLS Huber weights on SE(3) (left perturbation); returns (T, iterations)."""
    cost, H, g = _linearize(T, problem, robust, config.min_depth_m)
    lam = config.initial_damping
    iterations = 0
    for _ in range(config.iterations_per_round):
        iterations += 1
        damped = H + lam * np.diag(np.diag(H) + 1e-9)
        try:
            xi = -np.linalg.solve(damped, g)
        except np.linalg.LinAlgError:
            lam *= 10.0
            continue
        T_new = se3_exp(xi) @ T
        cost_new, H_new, g_new = _linearize(T_new, problem, robust, config.min_depth_m)
        if cost_new <= cost:
            T, cost, H, g = T_new, cost_new, H_new, g_new
            lam = max(lam * 0.1, 1e-12)
        else:
            lam *= 10.0
        if float(np.linalg.norm(xi)) < config.step_tolerance:
            break
    # Re-orthonormalise the rotation so repeated calls never drift off SO(3).
    U, _, Vt = np.linalg.svd(T[:3, :3])
    T[:3, :3] = U @ Vt
    return T, iterations
