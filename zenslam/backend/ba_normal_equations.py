"""Local BA's residuals and normal equations (in the blocks the Schur complement uses), each from one compiled pass over the observations.

For each observation row (whitened residual e = (u, v, u_right) and its Jacobians A = d e / d xi
(3x6, the observing pose, T * exp(xi)) and B = d e / d p_world (3x3)), gtsam's robust noise model
scales the row by sqrt(w) (Huber: w = 1 within the threshold, threshold / norm beyond), and

    U_f = sum A^T A,  g_pose_f = sum A^T e        over the rows on free pose f,
    V_p = sum B^T B,  g_point_p = sum B^T e       over the rows of point p,
    W_c = sum A^T B                               over the rows of cell c (point p seen by free pose f).

The Jacobians are those of ``schur_ba`` (whose module doc gives the model): with M = d e / d p_cam
= rows (a0, 0, c0), (0, b1, c1), (a2, 0, c2) from u = fx X/Z + cx, v = fy Y/Z + cy,
u_right = u - bf/Z, zero behind the camera (gtsam's factors give no Jacobian there), A = M [[p_cam]x, -I]
and B = M R^T. Sums run over the rows in their order, without fastmath: the same bits on every
x86-64 CPU and numba target.
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel, kernel_array


def project(
    T_world_cam: np.ndarray,
    p_world: np.ndarray,
    keyframe: np.ndarray,
    point: np.ndarray,
    measured: np.ndarray,
    weights: np.ndarray,
    intrinsics: tuple[float, float, float, float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observation rows' points in their cameras and their whitened residuals.

    Per row: ``keyframe`` and ``point`` index ``T_world_cam`` (K, 4, 4) and ``p_world`` (P, 3);
    ``measured`` (n, 3) is (u, v, u_right), u_right 0 on monocular rows; ``weights`` (n, 3) the
    whitening (w, w_right, w_cross); ``intrinsics`` = (fx, fy, cx, cy, bf). Returns ``camera``
    (n, 4): X, Y, Z in the camera and 1/Z (1 behind it), ``in_front`` (n,) Z > 0, and ``e`` (n, 3)
    = (w r_u, w r_v, w_right r_right + w_cross r_u); a point behind the camera gives gtsam's
    constant error, 2 fx on each residual.
    """
    fx, fy, cx, cy, bf = (float(v) for v in intrinsics)
    return _project(
        kernel_array(T_world_cam, np.float64), kernel_array(p_world, np.float64),
        kernel_array(keyframe, np.int64), kernel_array(point, np.int64),
        kernel_array(measured, np.float64), kernel_array(weights, np.float64), fx, fy, cx, cy, bf,
    )  # fmt: skip


def normal_equation_blocks(
    camera: np.ndarray,
    in_front: np.ndarray,
    T_world_cam: np.ndarray,
    keyframe: np.ndarray,
    e: np.ndarray,
    weights: np.ndarray,
    huber: np.ndarray,
    point_of: np.ndarray,
    pose_of: np.ndarray,
    n_points: int,
    n_free: int,
    intrinsics: tuple[float, float, float],
    robust: bool,
) -> tuple[np.ndarray, ...]:
    """(U, V, W, cell_point, cell_pose, g_pose, g_point) of the module doc.

    Per row, in the pass's order (by point, then keyframe): ``camera`` (n, 4) and ``in_front`` as
    ``project`` gives them, ``keyframe`` (n,) the observing keyframe's index into ``T_world_cam``
    (K, 4, 4), ``e`` (n, 3) whitened residuals, ``weights``
    (n, 3) the whitening (w, w_right, w_cross), ``huber`` (n,) the robust threshold, ``point_of``
    (n,) the variable point, ``pose_of`` (n,) the free pose or -1 on a fixed keyframe.
    ``intrinsics`` = (fx, fy, bf). The cells are numbered in row order: a run of rows of one point
    on one free pose is one cell.
    """
    fx, fy, bf = intrinsics
    return _blocks(
        kernel_array(camera, np.float64), kernel_array(in_front, np.bool_),
        kernel_array(T_world_cam, np.float64), kernel_array(keyframe, np.int64),
        kernel_array(e, np.float64),
        kernel_array(weights, np.float64), kernel_array(huber, np.float64),
        kernel_array(point_of, np.int64), kernel_array(pose_of, np.int64),
        int(n_points), int(n_free), float(fx), float(fy), float(bf), bool(robust),
    )  # fmt: skip


@kernel
def _project(T_world_cam, p_world, keyframe, point, measured, weights, fx, fy, cx, cy, bf):
    n = len(keyframe)
    camera = np.empty((n, 4))
    in_front = np.empty(n, np.bool_)
    e = np.empty((n, 3))
    for row in range(n):
        T, q = T_world_cam[keyframe[row]], p_world[point[row]]
        d0, d1, d2 = q[0] - T[0, 3], q[1] - T[1, 3], q[2] - T[2, 3]
        X = T[0, 0] * d0 + T[1, 0] * d1 + T[2, 0] * d2  # p_cam = R^T (p_world - t)
        Y = T[0, 1] * d0 + T[1, 1] * d1 + T[2, 1] * d2
        Z = T[0, 2] * d0 + T[1, 2] * d1 + T[2, 2] * d2
        front = Z > 0.0
        inv_z = 1.0 / Z if front else 1.0
        if front:
            u = fx * X * inv_z + cx
            r_u = u - measured[row, 0]
            r_v = fy * Y * inv_z + cy - measured[row, 1]
            r_right = u - bf * inv_z - measured[row, 2]
        else:  # gtsam's factors on a point behind the camera: a constant error
            r_u = r_v = r_right = 2.0 * fx
        camera[row, 0], camera[row, 1], camera[row, 2], camera[row, 3] = X, Y, Z, inv_z
        in_front[row] = front
        e[row, 0] = weights[row, 0] * r_u
        e[row, 1] = weights[row, 0] * r_v
        e[row, 2] = weights[row, 1] * r_right + weights[row, 2] * r_u
    return camera, in_front, e


@kernel
def _blocks(camera, in_front, T_world_cam, keyframe, e, weights, huber, point_of, pose_of, n_points, n_free, fx, fy, bf, robust):
    n = len(camera)
    U = np.zeros((n_free, 6, 6))
    V = np.zeros((n_points, 3, 3))
    g_pose = np.zeros((n_free, 6))
    g_point = np.zeros((n_points, 3))
    W = np.zeros((n, 6, 3))  # at most one cell per row
    cell_point = np.empty(n, np.int64)
    cell_pose = np.empty(n, np.int64)
    n_cells = 0
    A = np.zeros((3, 6))
    B = np.empty((3, 3))
    r = np.empty(3)
    for row in range(n):
        X, Y, Z, inv_z = camera[row, 0], camera[row, 1], camera[row, 2], camera[row, 3]
        w, w_right, w_cross = weights[row, 0], weights[row, 1], weights[row, 2]
        a0 = c0 = b1 = c1 = a2 = c2 = 0.0
        if in_front[row]:
            fx_z = fx * inv_z
            x_z2 = X * inv_z * inv_z
            a0 = w * fx_z
            c0 = -w * fx * x_z2
            b1 = w * (fy * inv_z)
            c1 = -w * (fy * Y * inv_z * inv_z)
            a2 = (w_right + w_cross) * fx_z
            c2 = w_right * bf * inv_z * inv_z - (w_right + w_cross) * fx * x_z2
        r[0], r[1], r[2] = e[row, 0], e[row, 1], e[row, 2]
        if robust:  # gtsam's robust noise model: the row reweighted by sqrt(w)
            norm = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
            k = huber[row]
            sqrt_w = np.sqrt(1.0 if norm <= k else k / (norm if norm > 0 else 1.0))
            a0, c0, b1, c1, a2, c2 = sqrt_w * a0, sqrt_w * c0, sqrt_w * b1, sqrt_w * c1, sqrt_w * a2, sqrt_w * c2
            r[0], r[1], r[2] = r[0] * sqrt_w, r[1] * sqrt_w, r[2] * sqrt_w
        # d p_cam = [p_cam]x omega - upsilon for T * exp(xi); d p_cam / d p_world = R^T
        A[0, 0], A[0, 1], A[0, 2], A[0, 3], A[0, 5] = -c0 * Y, c0 * X - a0 * Z, a0 * Y, -a0, -c0
        A[1, 0], A[1, 1], A[1, 2], A[1, 4], A[1, 5] = b1 * Z - c1 * Y, c1 * X, -b1 * X, -b1, -c1
        A[2, 0], A[2, 1], A[2, 2], A[2, 3], A[2, 5] = -c2 * Y, c2 * X - a2 * Z, a2 * Y, -a2, -c2
        T = T_world_cam[keyframe[row]]
        for j in range(3):  # B = M R^T: B[i, j] = sum_k M[i, k] R[j, k]
            B[0, j] = a0 * T[j, 0] + c0 * T[j, 2]
            B[1, j] = b1 * T[j, 1] + c1 * T[j, 2]
            B[2, j] = a2 * T[j, 0] + c2 * T[j, 2]
        p = point_of[row]
        for i in range(3):
            for j in range(3):
                V[p, i, j] += B[0, i] * B[0, j] + B[1, i] * B[1, j] + B[2, i] * B[2, j]
            g_point[p, i] += B[0, i] * r[0] + B[1, i] * r[1] + B[2, i] * r[2]
        f = pose_of[row]
        if f < 0:
            continue  # a fixed keyframe: no pose block
        for i in range(6):
            for j in range(6):
                U[f, i, j] += A[0, i] * A[0, j] + A[1, i] * A[1, j] + A[2, i] * A[2, j]
            g_pose[f, i] += A[0, i] * r[0] + A[1, i] * r[1] + A[2, i] * r[2]
        if n_cells == 0 or cell_point[n_cells - 1] != p or cell_pose[n_cells - 1] != f:
            cell_point[n_cells], cell_pose[n_cells] = p, f
            n_cells += 1
        c = n_cells - 1
        for i in range(6):
            for j in range(3):
                W[c, i, j] += A[0, i] * B[0, j] + A[1, i] * B[1, j] + A[2, i] * B[2, j]
    return U, V, W[:n_cells].copy(), cell_point[:n_cells].copy(), cell_pose[:n_cells].copy(), g_pose, g_point
