"""Local bundle adjustment on the reduced camera system: Levenberg-Marquardt with the landmarks
eliminated by their Schur complement, vectorised in numpy.

The problem, its passes and its result are those of ``local_ba.LocalBundleAdjuster`` (ORB-SLAM's
``Optimizer::LocalBundleAdjustment`` as gtsam factors; see that module): the same residuals
(left (u, v) and, for stereo / RGB-D rows, the right u), the same noise models (isotropic, a
scaled right u, RGB-D's correlated virtual right u), Huber on the whitened residual norm, the same
two passes, stopping rules, damping floor, chi2 classification and points held or removed. What
differs is how each Levenberg-Marquardt step is solved. gtsam eliminates the landmarks one at a
time through its generic factor machinery (a HessianFactor assembled, factored and combined per
landmark: the largest part of a window's time, benchmarks/local_ba.md). BA
solvers (g2o's block solver, which ORB-SLAM uses; Ceres' SPARSE_SCHUR) instead exploit that a
landmark's 3x3 block touches only the poses that see it: every landmark block is factored at once
(Cholesky), the reduced camera system (6 x free poses, square) is assembled block by block from
the poses that see each landmark, and the landmarks' steps follow by back-substitution. Here the
linearisation is a few array operations over all observations and the reduced system and the
back-substitution are compiled loops (``schur_complement``). The reduced system is solved
densely, which suits a local window (~10-20 free poses); global BA, over every keyframe of the
map, keeps gtsam's sparse elimination (``global_ba``).

The step is the one gtsam's Levenberg-Marquardt takes: the Gauss-Newton system of the whitened,
Huber-reweighted residuals (gtsam's robust noise model reweights each observation by
sqrt(w), w = 1 within Huber's threshold, threshold / norm beyond) with lambda * I added to every
variable's block, a step accepted when it lowers the error (lambda / 10, not below the floor),
rejected otherwise (lambda * 10, up to 1e5). A pose moves as T_world_cam * exp(xi), xi = (omega,
upsilon); a point by addition. A point behind a camera gives gtsam's constant error (2 fx per
component) and no Jacobian. Both solvers reach the same optimum (tests compare them on the same
windows); their results differ in the last digits.

Determinism: numpy (elementwise arithmetic, reductions in a fixed order, matrix products and
``np.linalg.solve`` through OpenBLAS, whose kernels and single thread the stages pin) and compiled
loops in a fixed order without fastmath, so lockstep runs give the same bits on any x86-64 CPU.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from zenslam.backend.ba_problem import BAProblem, BAResult, LocalBAConfig, ba_stats, constrained_points
from zenslam.geometry import se3_exp

logger = logging.getLogger(__name__)

LAMBDA_FACTOR = 10.0  # gtsam's LevenbergMarquardtParams.lambdaFactor
LAMBDA_UPPER_BOUND = 1e5  # gtsam's lambdaUpperBound: a pass ends when no step is accepted below it


class SchurBundleAdjuster:
    """Runs local BA on windows handed over one at a time; keeps no state between calls."""

    def __init__(self, config: LocalBAConfig) -> None:
        self.config = config

    def optimize(self, problem: BAProblem) -> BAResult:
        """Optimise the non-fixed poses and the constrained points of ``problem`` (see module doc)."""
        start = time.perf_counter()
        config = self.config
        rows = _Rows.of(problem, config)
        state = _State(problem.T_world_cam.copy(), problem.p_world.copy())
        dropped = ~np.isfinite(state.p_world).all(axis=1)
        state.p_world[dropped] = 0.0  # never read: their observations take part in nothing
        active = rows.usable & ~dropped[problem.obs_point]
        # The one-step refinement after a robust pass keeps Huber's kernel, as local_ba's does.
        schedule = [(True, config.robust_iterations)]
        if config.two_passes:
            reuse = config.refine_iterations == 1 and config.robust_iterations > 0
            schedule.append((reuse, config.refine_iterations))
        for robust, iterations in schedule:
            if iterations > 0:
                _run_pass(problem, rows, state, active, robust, iterations, config)
            active = rows.classify(problem, state) & ~dropped[problem.obs_point]
        state.p_world[dropped] = problem.p_world[dropped]
        T_world_cam = state.T_world_cam
        T_world_cam[problem.fixed] = problem.T_world_cam[problem.fixed]
        has_inlier = np.bincount(problem.obs_point[active], minlength=len(problem.point_ids)) > 0
        removed = problem.point_ids[~has_inlier]
        stats = ba_stats(
            config, iterations=state.iterations, initial_error=state.initial_error, final_error=state.final_error,
            seconds=time.perf_counter() - start, inlier_obs=active, removed_point_ids=removed,
            n_dropped_points=int(dropped.sum()), passes=state.passes,
            retries=0,  # nothing to repair: damping keeps every landmark block invertible
            failure=None,
        )
        logger.debug("local BA: %s", stats)
        return BAResult(T_world_cam, state.p_world, active, removed, stats)


def load_compiled_kernels() -> None:
    """Load the compiled kernels of the solve from numba's cache (compile them, on a machine's first
    start), on a one-observation problem: for the backend to call at its start, so that its first
    local BA does not wait for numba's start and the load (most of a second; ~60 MB)."""
    from zenslam.backend import ba_normal_equations, schur_complement

    T, p, index = np.eye(4)[None], np.array([[0.0, 0.0, 5.0]]), np.zeros(1, np.int64)
    camera, in_front, e = ba_normal_equations.project(T, p, index, index, np.zeros((1, 3)), np.ones((1, 3)), (1.0, 1.0, 0.0, 0.0, 1.0))
    U, V, W, cell_point, cell_pose, g_pose, g_point = ba_normal_equations.normal_equation_blocks(
        camera, in_front, T, index, e, np.ones((1, 3)), np.ones(1), index, index, 1, 1, (1.0, 1.0, 1.0), True
    )
    C_inv = _inverse_cholesky_3x3(V + np.eye(3))
    S, r, Z, h = schur_complement.reduced_system(W, C_inv, cell_point, cell_pose, g_point, U + np.eye(6), g_pose)
    schur_complement.back_substitute(Z, C_inv, cell_point, cell_pose, h, np.linalg.solve(S, r))


@dataclass
class _State:
    """The estimate as it evolves over the passes, plus what the stats report."""

    T_world_cam: np.ndarray
    p_world: np.ndarray
    iterations: int = 0
    passes: int = 0
    initial_error: float = math.nan
    final_error: float = math.nan


@dataclass(frozen=True)
class _Rows:
    """Per observation: whether it is usable, its whitening and its robust and outlier thresholds.

    Residuals are ordered (u, v, u_right) and whitened as e = (w r_u, w r_v, w_right r_right +
    w_cross r_u): w = 1/sigma; w_right = 1/(sigma * scale) for a stereo row, 1/d for an RGB-D
    one, whose virtual u_right = u - bf / depth shares u's keypoint error, so the independent part
    is the difference u - u_right (the disparity, from the depth sensor, sigma d), hence w_cross =
    -1/d; both 0 on a monocular row, whose third residual then counts for nothing.
    """

    usable: np.ndarray  # (O,) bool: finite pixel and positive information
    stereo: np.ndarray  # (O,) bool
    w: np.ndarray  # (O,) 1/px
    w_right: np.ndarray  # (O,) 1/px
    w_cross: np.ndarray  # (O,) 1/px
    right_u: np.ndarray  # (O,) px, 0 on monocular rows
    huber: np.ndarray  # (O,) Huber threshold on the whitened residual norm
    chi2_threshold: np.ndarray  # (O,)
    fx: float
    fy: float
    cx: float
    cy: float
    bf: float  # px * m; 0 for a window without stereo rows
    min_depth_m: float  # a point nearer than this along the optical axis is behind the camera

    @staticmethod
    def of(problem: BAProblem, config: LocalBAConfig) -> _Rows:
        c = problem.calibration
        info = problem.obs_inv_sigma2
        usable = np.isfinite(problem.obs_px).all(axis=1) & np.isfinite(info) & (info > 0)
        stereo = usable & np.isfinite(problem.obs_right_u)
        w = np.sqrt(np.where(usable, info, 0.0))
        scale = np.ones(len(info)) if problem.obs_right_sigma_scale is None else problem.obs_right_sigma_scale
        disparity = np.zeros(len(info)) if problem.obs_disparity_sigma is None else np.nan_to_num(problem.obs_disparity_sigma)
        rgbd = stereo & (disparity > 0)
        inv_disparity = 1.0 / np.where(rgbd, disparity, 1.0)
        return _Rows(
            usable=usable,
            stereo=stereo,
            w=w,
            w_right=np.where(rgbd, inv_disparity, np.where(stereo, w / scale, 0.0)),
            w_cross=np.where(rgbd, -inv_disparity, 0.0),
            right_u=np.where(stereo, problem.obs_right_u, 0.0),
            huber=np.where(stereo, config.huber_stereo, config.huber_mono),
            chi2_threshold=np.where(stereo, config.chi2_stereo, config.chi2_mono),
            fx=c.fx, fy=c.fy, cx=c.cx, cy=c.cy,
            bf=c.bf if stereo.any() else 0.0,
            min_depth_m=config.min_depth_m,
        )  # fmt: skip

    def project(self, problem: BAProblem, rows: np.ndarray, T_world_cam: np.ndarray, p_world: np.ndarray) -> _Projection:
        """The observation ``rows``' points in their cameras and their whitened residuals (``ba_normal_equations.project``)."""
        from zenslam.backend.ba_normal_equations import project  # numba: see _solve

        measured = np.empty((len(rows), 3))
        measured[:, :2] = problem.obs_px[rows]
        measured[:, 2] = self.right_u[rows]
        weights = np.stack([self.w[rows], self.w_right[rows], self.w_cross[rows]], axis=1)
        camera, in_front, e = project(
            T_world_cam, p_world, problem.obs_keyframe[rows], problem.obs_point[rows], measured, weights,
            (self.fx, self.fy, self.cx, self.cy, self.bf),
        )
        return _Projection(camera, in_front, weights, e)

    def classify(self, problem: BAProblem, state: _State) -> np.ndarray:
        """(O,) inlier mask at the current estimate: usable, in front of the camera, chi2 within threshold."""
        rows = np.flatnonzero(self.usable)
        inlier = np.zeros(len(self.usable), dtype=bool)
        if len(rows):
            with np.errstate(invalid="ignore", over="ignore"):
                projection = self.project(problem, rows, state.T_world_cam, state.p_world)
                chi2 = (projection.e * projection.e).sum(axis=1)
                inlier[rows] = (projection.Z > self.min_depth_m) & (chi2 <= self.chi2_threshold[rows])
        return inlier


@dataclass(frozen=True)
class _Projection:
    """Observations' points in their cameras and whitened residuals at one estimate."""

    camera: np.ndarray  # (n, 4): X, Y, Z (m) in the camera and 1/Z (1/m; 1 behind the camera)
    in_front: np.ndarray  # (n,) bool
    weights: np.ndarray  # (n, 3) the rows' whitening: w, w_right, w_cross (1/px)
    e: np.ndarray  # (n, 3) whitened residuals

    @property
    def Z(self) -> np.ndarray:
        return self.camera[:, 2]


@dataclass(frozen=True)
class _Structure:
    """One pass's variables and the index arrays that its steps reuse.

    The pass's observation rows are ordered by point, then keyframe, so each point's rows are
    contiguous; points and free poses are numbered from 0 in the order of their rows in the
    problem. A cell is a point and a free pose that sees it (a run of rows in this order): the
    point-pose coupling J_pose^T J_point has one 6x3 block per cell.
    """

    rows: np.ndarray  # (n,) observation rows of the pass, by point then keyframe
    point_rows: np.ndarray  # (L,) problem point rows that are variables
    point_of: np.ndarray  # (n,) variable point of each row
    free_pose_rows: np.ndarray  # (F,) problem keyframe rows that are variables
    pose_of: np.ndarray  # (n,) free pose of each row, -1 on a fixed keyframe

    @staticmethod
    def of(problem: BAProblem, rows: np.ndarray) -> _Structure:
        n_keyframes = len(problem.keyframe_ids)
        rows = rows[np.argsort(problem.obs_point[rows] * n_keyframes + problem.obs_keyframe[rows], kind="stable")]
        point_rows, point_of = np.unique(problem.obs_point[rows], return_inverse=True)
        kf = problem.obs_keyframe[rows]
        on_free = ~problem.fixed[kf]
        free_pose_rows, free_index = np.unique(kf[on_free], return_inverse=True)
        pose_of = np.full(len(rows), -1, dtype=np.intp)
        pose_of[on_free] = free_index
        return _Structure(rows=rows, point_rows=point_rows, point_of=point_of, free_pose_rows=free_pose_rows, pose_of=pose_of)


@dataclass(frozen=True)
class _Evaluation:
    """The pass's residuals at one estimate."""

    T_world_cam: np.ndarray
    p_world: np.ndarray
    projection: _Projection
    cost: float  # gtsam's error: 0.5 |e|^2 per row, Huber's loss when robust; inf when not finite


@dataclass(frozen=True)
class _Linearized:
    """The whitened, reweighted normal equations at one estimate, in the blocks the Schur complement uses."""

    U: np.ndarray  # (F, 6, 6) J_pose^T J_pose per free pose
    V: np.ndarray  # (L, 3, 3) J_point^T J_point per point
    W: np.ndarray  # (c, 6, 3) J_pose^T J_point per cell: a point and a free pose that sees it
    cell_point: np.ndarray  # (c,) the cell's point
    cell_pose: np.ndarray  # (c,) the cell's free pose
    g_pose: np.ndarray  # (F, 6) J_pose^T e
    g_point: np.ndarray  # (L, 3) J_point^T e


def _run_pass(
    problem: BAProblem, rows_info: _Rows, state: _State, active: np.ndarray, robust: bool, iterations: int,
    config: LocalBAConfig,
) -> None:
    """Levenberg-Marquardt on the active observations of constrained points, at most ``iterations`` steps."""
    rows = np.flatnonzero(active & constrained_points(problem, rows_info.stereo, active)[problem.obs_point])
    if len(rows) == 0:
        return
    structure = _Structure.of(problem, rows)
    lam = config.lambda_initial
    current = _evaluate(problem, rows_info, structure.rows, state.T_world_cam, state.p_world, robust)
    if math.isnan(state.initial_error):
        state.initial_error = current.cost
    done = 0
    while done < iterations:
        done += 1
        linear = _linearize(problem, rows_info, structure, current, robust)
        accepted = False
        while not accepted and lam < LAMBDA_UPPER_BOUND:  # damp more until a step lowers the error
            step = _solve(linear, lam)
            if step is not None:
                T_new, p_new = _apply(structure, current.T_world_cam, current.p_world, *step)
                candidate = _evaluate(problem, rows_info, structure.rows, T_new, p_new, robust)
                accepted = candidate.cost < current.cost
            if not accepted:
                lam *= LAMBDA_FACTOR
        if not accepted:  # converged as far as damping allows
            break
        lam = max(lam / LAMBDA_FACTOR, config.lambda_lower_bound)
        decrease = current.cost - candidate.cost
        relative = decrease / current.cost
        current = candidate
        if current.cost <= 0.0 or relative <= config.relative_error_tolerance or decrease <= config.absolute_error_tolerance:
            break
    state.T_world_cam, state.p_world = current.T_world_cam, current.p_world
    state.iterations += done
    state.passes += 1
    state.final_error = current.cost


def _evaluate(
    problem: BAProblem, rows_info: _Rows, rows: np.ndarray, T_world_cam: np.ndarray, p_world: np.ndarray, robust: bool
) -> _Evaluation:
    with np.errstate(invalid="ignore", over="ignore"):
        projection = rows_info.project(problem, rows, T_world_cam, p_world)
        cost = _loss((projection.e * projection.e).sum(axis=1), rows_info.huber[rows], robust)
    return _Evaluation(T_world_cam, p_world, projection, cost if math.isfinite(cost) else math.inf)


def _linearize(problem: BAProblem, f: _Rows, s: _Structure, at: _Evaluation, robust: bool) -> _Linearized:
    """The normal equations' blocks at ``at`` (``ba_normal_equations``: the Jacobians, Huber's reweighting, the sums)."""
    from zenslam.backend.ba_normal_equations import normal_equation_blocks  # numba: see _solve

    rows, q = s.rows, at.projection
    U, V, W, cell_point, cell_pose, g_pose, g_point = normal_equation_blocks(
        q.camera, q.in_front, at.T_world_cam, problem.obs_keyframe[rows], q.e, q.weights, f.huber[rows],
        s.point_of, s.pose_of, len(s.point_rows), len(s.free_pose_rows), (f.fx, f.fy, f.bf), robust,
    )  # fmt: skip
    return _Linearized(U, V, W, cell_point, cell_pose, g_pose, g_point)


def _solve(linear: _Linearized, lam: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The damped step (free poses (F, 6), points (L, 3)), or None when it is not finite.

    Normal equations [U W; W^T V] [d_pose; d_point] = -[g_pose; g_point], each block damped by
    lam * I. The points are eliminated (``schur_complement``): with V = C C^T (Cholesky, per point)
    and Z = W C^-T, the reduced camera system is S = U - Z Z^T, its right-hand side Z h - g_pose
    with h = C^-1 g_point; then d_point = -C^-T (h + Z^T d_pose).
    """
    # Imported here: the compiled kernels load numba (~60 MB), which the backend's other work and
    # the processes that only read a LocalBAConfig do not need before a first local BA.
    from zenslam.backend import schur_complement

    C_inv = _inverse_cholesky_3x3(linear.V + lam * np.eye(3))
    S, r, Z, h = schur_complement.reduced_system(
        linear.W, C_inv, linear.cell_point, linear.cell_pose, linear.g_point, linear.U + lam * np.eye(6), linear.g_pose
    )
    if len(linear.U):
        try:
            d_pose = np.linalg.solve(S, r)
        except np.linalg.LinAlgError:
            return None
    else:
        d_pose = np.zeros(0)
    d_point = schur_complement.back_substitute(Z, C_inv, linear.cell_point, linear.cell_pose, h, d_pose)
    d_pose = d_pose.reshape(-1, 6)
    if not (np.isfinite(d_pose).all() and np.isfinite(d_point).all()):
        return None
    return d_pose, d_point


def _apply(s: _Structure, T_world_cam: np.ndarray, p_world: np.ndarray, d_pose: np.ndarray, d_point: np.ndarray):
    """The estimate moved by a step: T * exp(xi) for free poses, p + d for points (copies)."""
    T_new = T_world_cam.copy()
    for row, xi in zip(s.free_pose_rows.tolist(), d_pose):
        T_new[row] = T_world_cam[row] @ se3_exp(xi)
    p_new = p_world.copy()
    p_new[s.point_rows] += d_point
    return T_new, p_new


def _loss(norm2: np.ndarray, huber: np.ndarray, robust: bool) -> float:
    """gtsam's error: 0.5 d^2 per row, or Huber's 0.5 d^2 within k and k d - 0.5 k^2 beyond."""
    if not robust:
        return float(0.5 * norm2.sum())
    norm = np.sqrt(norm2)
    return float(np.where(norm <= huber, 0.5 * norm2, huber * norm - 0.5 * huber * huber).sum())


def _inverse_cholesky_3x3(V: np.ndarray) -> np.ndarray:
    """C^-1 (lower triangular) of V = C C^T, for (N, 3, 3) symmetric positive definite matrices."""
    v00, v10, v11, v20, v21, v22 = V[:, 0, 0], V[:, 1, 0], V[:, 1, 1], V[:, 2, 0], V[:, 2, 1], V[:, 2, 2]
    with np.errstate(invalid="ignore", divide="ignore"):  # a matrix that is not positive definite gives NaN
        c00 = np.sqrt(v00)
        c10, c20 = v10 / c00, v20 / c00
        c11 = np.sqrt(v11 - c10 * c10)
        c21 = (v21 - c20 * c10) / c11
        c22 = np.sqrt(v22 - c20 * c20 - c21 * c21)
        inverse = np.zeros_like(V)
        inverse[:, 0, 0] = i00 = 1.0 / c00
        inverse[:, 1, 1] = i11 = 1.0 / c11
        inverse[:, 2, 2] = i22 = 1.0 / c22
        inverse[:, 1, 0] = i10 = -c10 * i00 * i11
        inverse[:, 2, 1] = -c21 * i11 * i22
        inverse[:, 2, 0] = -(c20 * i00 + c21 * i10) * i22
    return inverse
