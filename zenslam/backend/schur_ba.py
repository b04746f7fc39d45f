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
(Cholesky), the reduced camera system (6 x free poses, square) is assembled as one product and
solved densely, and the landmarks' steps follow by back-substitution. Here each of those is a few
array operations over all observations. The reduced system is held densely, which suits a local
window (~10 free poses); global BA, over every keyframe of the map, keeps gtsam's sparse
elimination (``global_ba``).

The step is the one gtsam's Levenberg-Marquardt takes: the Gauss-Newton system of the whitened,
Huber-reweighted residuals (gtsam's robust noise model reweights each observation by
sqrt(w), w = 1 within Huber's threshold, threshold / norm beyond) with lambda * I added to every
variable's block, a step accepted when it lowers the error (lambda / 10, not below the floor),
rejected otherwise (lambda * 10, up to 1e5). A pose moves as T_world_cam * exp(xi), xi = (omega,
upsilon); a point by addition. A point behind a camera gives gtsam's constant error (2 fx per
component) and no Jacobian. Both solvers reach the same optimum (tests compare them on the same
windows); their results differ in the last digits.

Determinism: only numpy (elementwise arithmetic, reductions in a fixed order, matrix products and
``np.linalg.solve`` through OpenBLAS, whose kernels and single thread the stages pin), so lockstep
runs give the same bits on any x86-64 CPU.
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
        """The observation ``rows``' points in their cameras and their whitened residuals."""
        kf = problem.obs_keyframe[rows]
        R = np.ascontiguousarray(T_world_cam[:, :3, :3]).reshape(-1, 9)[kf]  # row-major R per row
        d = p_world[problem.obs_point[rows]] - T_world_cam[kf, :3, 3]
        d0, d1, d2 = d[:, 0], d[:, 1], d[:, 2]
        X = R[:, 0] * d0 + R[:, 3] * d1 + R[:, 6] * d2  # p_cam = R^T (p_world - t)
        Y = R[:, 1] * d0 + R[:, 4] * d1 + R[:, 7] * d2
        Z = R[:, 2] * d0 + R[:, 5] * d1 + R[:, 8] * d2
        in_front = Z > 0.0
        inv_z = 1.0 / np.where(in_front, Z, 1.0)
        u = self.fx * X * inv_z + self.cx
        r_u = u - problem.obs_px[rows, 0]
        r_v = self.fy * Y * inv_z + self.cy - problem.obs_px[rows, 1]
        r_right = u - self.bf * inv_z - self.right_u[rows]
        behind = ~in_front
        if behind.any():  # gtsam's factors on a point behind the camera: a constant error
            r_u[behind] = r_v[behind] = r_right[behind] = 2.0 * self.fx
        w = self.w[rows]
        e = np.empty((len(rows), 3))
        e[:, 0] = w * r_u
        e[:, 1] = w * r_v
        e[:, 2] = self.w_right[rows] * r_right + self.w_cross[rows] * r_u
        return _Projection(X, Y, Z, inv_z, in_front, R, e)

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

    X: np.ndarray  # (n,) m
    Y: np.ndarray  # (n,) m
    Z: np.ndarray  # (n,) m
    inv_z: np.ndarray  # (n,) 1/m, 1 behind the camera
    in_front: np.ndarray  # (n,) bool
    R: np.ndarray  # (n, 9) the observing camera's rotation (camera to world), row-major
    e: np.ndarray  # (n, 3) whitened residuals


@dataclass(frozen=True)
class _Structure:
    """One pass's variables and the index arrays that its steps reuse.

    The pass's observation rows are ordered by point, then keyframe, so each point's rows are
    contiguous; points and free poses are numbered from 0 in the order of their rows in the
    problem. A cell is a point and a free pose that sees it: the point-pose coupling J_pose^T
    J_point has one 6x3 block per cell.
    """

    rows: np.ndarray  # (n,) observation rows of the pass, by point then keyframe
    point_rows: np.ndarray  # (L,) problem point rows that are variables
    point_of: np.ndarray  # (n,) variable point of each row
    point_starts: np.ndarray  # (L,) where each point's rows start
    free_pose_rows: np.ndarray  # (F,) problem keyframe rows that are variables
    pose_of: np.ndarray  # (n,) free pose of each row, -1 on a fixed keyframe
    free: np.ndarray  # (m,) the rows on free poses
    by_pose: np.ndarray  # (m,) the rows on free poses, by pose
    pose_ends: np.ndarray  # (F,) where each free pose's rows end in by_pose
    cell_starts: np.ndarray | None  # where each (point, free pose) group starts in free; None: one row each

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
        free = np.flatnonzero(on_free)
        by_pose = free[np.argsort(pose_of[free], kind="stable")]
        cell = point_of[free] * n_keyframes + kf[free]
        cell_starts = _group_starts(cell)
        return _Structure(
            rows=rows,
            point_rows=point_rows,
            point_of=point_of,
            point_starts=_group_starts(point_of),
            free_pose_rows=free_pose_rows,
            pose_of=pose_of,
            free=free,
            by_pose=by_pose,
            pose_ends=np.cumsum(np.bincount(pose_of[free], minlength=len(free_pose_rows))),
            cell_starts=None if len(cell_starts) == len(free) else cell_starts,
        )


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
    rows, q = s.rows, at.projection
    X, Y, Z, inv_z, R, e = q.X, q.Y, q.Z, q.inv_z, q.R, q.e
    # M = d e / d p_cam (whitened), zero behind the camera (gtsam's factors give no Jacobian there):
    # rows (a0, 0, c0), (0, b1, c1), (a2, 0, c2), from u = fx X/Z + cx, v = fy Y/Z + cy, u_right = u - bf/Z.
    w, w_right, w_cross = f.w[rows], f.w_right[rows], f.w_cross[rows]
    fx_z = np.where(q.in_front, f.fx * inv_z, 0.0)
    x_z2 = X * inv_z * inv_z
    a0 = w * fx_z
    c0 = np.where(q.in_front, -w * f.fx * x_z2, 0.0)
    b1 = w * np.where(q.in_front, f.fy * inv_z, 0.0)
    c1 = -w * np.where(q.in_front, f.fy * Y * inv_z * inv_z, 0.0)
    a2 = (w_right + w_cross) * fx_z
    c2 = np.where(q.in_front, w_right * f.bf * inv_z * inv_z - (w_right + w_cross) * f.fx * x_z2, 0.0)
    if robust:  # gtsam's robust noise model: rows reweighted by sqrt(w)
        norm = np.sqrt((e * e).sum(axis=1))
        k = f.huber[rows]
        sqrt_w = np.sqrt(np.where(norm <= k, 1.0, k / np.where(norm > 0, norm, 1.0)))
        a0, c0, b1, c1, a2, c2 = (sqrt_w * x for x in (a0, c0, b1, c1, a2, c2))
        e = e * sqrt_w[:, None]
    # d p_cam = [p_cam]x omega - upsilon for T * exp(xi); d p_cam / d p_world = R^T
    A = np.zeros((len(rows), 3, 6))
    A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3], A[:, 0, 5] = -c0 * Y, c0 * X - a0 * Z, a0 * Y, -a0, -c0
    A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 4], A[:, 1, 5] = b1 * Z - c1 * Y, c1 * X, -b1 * X, -b1, -c1
    A[:, 2, 0], A[:, 2, 1], A[:, 2, 2], A[:, 2, 3], A[:, 2, 5] = -c2 * Y, c2 * X - a2 * Z, a2 * Y, -a2, -c2
    # B = M R^T = d e / d p_world, entry by entry as whole arrays over the rows: b[i][j] = B[:, i, j]
    R_entries = [np.ascontiguousarray(R[:, k]) for k in range(9)]  # R[j, k] is R_entries[3 * j + k]
    b = [
        [a0 * R_entries[3 * j] + c0 * R_entries[3 * j + 2] for j in range(3)],
        [b1 * R_entries[3 * j + 1] + c1 * R_entries[3 * j + 2] for j in range(3)],
        [a2 * R_entries[3 * j] + c2 * R_entries[3 * j + 2] for j in range(3)],
    ]
    # B^T B and B^T e per row from those arrays: the sums numpy's stacked 3x3 matmul makes, in its
    # order (the same bits), in a fraction of its time on a window's rows (it loops matrix by matrix;
    # benchmarks/local_ba.md).
    n_rows = len(rows)
    BtB = np.empty((n_rows, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            BtB[:, i, j] = BtB[:, j, i] = b[0][i] * b[0][j] + b[1][i] * b[1][j] + b[2][i] * b[2][j]
    e_entries = [np.ascontiguousarray(e[:, k]) for k in range(3)]
    Bte = np.empty((n_rows, 3))
    for i in range(3):
        Bte[:, i] = b[0][i] * e_entries[0] + b[1][i] * e_entries[1] + b[2][i] * e_entries[2]
    V = np.add.reduceat(BtB, s.point_starts, axis=0)
    g_point = np.add.reduceat(Bte, s.point_starts, axis=0)
    n_free = len(s.free_pose_rows)
    U = np.empty((n_free, 6, 6))
    g_pose = np.empty((n_free, 6))
    A_pose, e_pose = A[s.by_pose], e[s.by_pose]
    start = 0
    for f_index, end in enumerate(s.pose_ends.tolist()):  # one product per free pose: its rows stacked
        J = A_pose[start:end].reshape(-1, 6)
        U[f_index] = J.T @ J
        g_pose[f_index] = J.T @ e_pose[start:end].reshape(-1)
        start = end
    free = s.free
    B = np.empty((len(free), 3, 3))
    for i in range(3):
        for j in range(3):
            B[:, i, j] = b[i][j][free]
    W = A[free].transpose(0, 2, 1) @ B
    if s.cell_starts is not None:  # a point seen twice by one keyframe: sum its rows
        W = np.add.reduceat(W, s.cell_starts, axis=0)
        free = free[s.cell_starts]
    return _Linearized(U, V, W, s.point_of[free], s.pose_of[free], g_pose, g_point)


def _solve(linear: _Linearized, lam: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The damped step (free poses (F, 6), points (L, 3)), or None when it is not finite.

    Normal equations [U W; W^T V] [d_pose; d_point] = -[g_pose; g_point], each block damped by
    lam * I. The points are eliminated: with V = C C^T (Cholesky, per point) and Z = W C^-T, the
    reduced camera system is S = U - Z Z^T, its right-hand side Z h - g_pose with h = C^-1 g_point;
    then d_point = -C^-T (h + Z^T d_pose).
    """
    n_points, n_free = len(linear.V), len(linear.U)
    C_inv = _inverse_cholesky_3x3(linear.V + lam * np.eye(3))
    h = (C_inv @ linear.g_point[:, :, None])[:, :, 0]
    if n_free:
        Z = np.zeros((n_free, 6, n_points, 3))  # dense (pose, 6) x (point, 3): S is one product
        Z[linear.cell_pose, :, linear.cell_point, :] = linear.W @ C_inv[linear.cell_point].transpose(0, 2, 1)
        Z = Z.reshape(6 * n_free, 3 * n_points)
        S = -(Z @ Z.T)  # numpy computes a product with its own transpose as a symmetric rank-k update
        U = linear.U + lam * np.eye(6)
        for f in range(n_free):
            S[6 * f : 6 * f + 6, 6 * f : 6 * f + 6] += U[f]
        try:
            d_pose = np.linalg.solve(S, Z @ h.reshape(-1) - linear.g_pose.reshape(-1))
        except np.linalg.LinAlgError:
            return None
        h = h + (d_pose @ Z).reshape(n_points, 3)
        d_pose = d_pose.reshape(n_free, 6)
    else:
        d_pose = np.zeros((0, 6))
    d_point = -(C_inv.transpose(0, 2, 1) @ h[:, :, None])[:, :, 0]
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


def _group_starts(sorted_ids: np.ndarray) -> np.ndarray:
    """Where each run of equal values starts in a sorted array."""
    if len(sorted_ids) == 0:
        return np.zeros(0, dtype=np.intp)
    return np.flatnonzero(np.concatenate(([True], sorted_ids[1:] != sorted_ids[:-1])))


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
