"""Local BA's reduced camera system and back-substitution, compiled: the sparse Schur complement of the points.

The normal equations of a window are [U W; W^T V] [d_pose; d_point] = -[g_pose; g_point] with one
3x3 block V_p per point, one 6x6 block U_f per free pose and one 6x3 block W_c per cell (a point
and a free pose that sees it). With V_p = C_p C_p^T and Z_c = W_c C_p^-T, eliminating the points
leaves the reduced camera system

    S d_pose = r,  S = U - sum_p Z_p Z_p^T,  r = sum_c Z_c h_p - g_pose,  h_p = C_p^-1 g_point_p,

where Z_p Z_p^T only has blocks between the free poses that see p: a point seen by k free poses
adds k (k + 1) / 2 6x6 blocks, so S costs the sum of those over the points instead of the dense
(6 F x 3 L) product, and nothing of size F x L is formed. The points' steps follow as
d_point_p = -C_p^-T (h_p + sum_c Z_c^T d_pose_f).

Every sum runs in one fixed order (points ascending, a point's cells by free pose), without BLAS
and without fastmath, so the result has the same bits on every x86-64 CPU and numba target.
"""

from __future__ import annotations

import numpy as np

from zenslam.compiled import kernel, kernel_array


def reduced_system(
    W: np.ndarray,
    C_inv: np.ndarray,
    cell_point: np.ndarray,
    cell_pose: np.ndarray,
    g_point: np.ndarray,
    U_damped: np.ndarray,
    g_pose: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """S (6F, 6F), r (6F,), the cells' Z (c, 6, 3) and the points' h (L, 3) of the module doc.

    ``W`` (c, 6, 3) per cell, ``C_inv`` (L, 3, 3) the points' inverse Cholesky factors, ``cell_point``
    and ``cell_pose`` (c,) the cell's point and free pose with the cells sorted by point and, within
    a point, by pose; ``g_point`` (L, 3); ``U_damped`` (F, 6, 6) the free poses' blocks with their damping;
    ``g_pose`` (F, 6).
    """
    return _reduced_system(
        kernel_array(W, np.float64), kernel_array(C_inv, np.float64),
        kernel_array(cell_point, np.int64), kernel_array(cell_pose, np.int64),
        kernel_array(g_point, np.float64), kernel_array(U_damped, np.float64),
        kernel_array(g_pose, np.float64),
    )  # fmt: skip


def back_substitute(Z: np.ndarray, C_inv: np.ndarray, cell_point: np.ndarray, cell_pose: np.ndarray, h: np.ndarray, d_pose: np.ndarray) -> np.ndarray:
    """The points' steps (L, 3): d_point_p = -C_p^-T (h_p + sum over p's cells of Z_c^T d_pose_f)."""
    return _back_substitute(
        kernel_array(Z, np.float64), kernel_array(C_inv, np.float64),
        kernel_array(cell_point, np.int64), kernel_array(cell_pose, np.int64),
        kernel_array(h, np.float64), kernel_array(d_pose, np.float64).reshape(-1, 6),
    )  # fmt: skip


@kernel
def _reduced_system(W, C_inv, cell_point, cell_pose, g_point, U_damped, g_pose):
    n_cells, n_free = len(W), len(U_damped)
    h = np.empty_like(g_point)
    for p in range(len(h)):  # h = C^-1 g_point
        for i in range(3):
            h[p, i] = C_inv[p, i, 0] * g_point[p, 0] + C_inv[p, i, 1] * g_point[p, 1] + C_inv[p, i, 2] * g_point[p, 2]
    Z = np.empty((n_cells, 6, 3))
    for c in range(n_cells):  # Z_c = W_c C_p^-T: (Z_c)[i, j] = sum_k W_c[i, k] C_p^-1[j, k]
        p = cell_point[c]
        for i in range(6):
            for j in range(3):
                Z[c, i, j] = W[c, i, 0] * C_inv[p, j, 0] + W[c, i, 1] * C_inv[p, j, 1] + W[c, i, 2] * C_inv[p, j, 2]
    S = np.zeros((6 * n_free, 6 * n_free))
    r = np.zeros(6 * n_free)
    start = 0
    while start < n_cells:  # one point's cells at a time
        p = cell_point[start]
        end = start + 1
        while end < n_cells and cell_point[end] == p:
            end += 1
        for a in range(start, end):
            fa = 6 * cell_pose[a]
            for i in range(6):
                r[fa + i] += Z[a, i, 0] * h[p, 0] + Z[a, i, 1] * h[p, 1] + Z[a, i, 2] * h[p, 2]
            for b in range(a, end):  # upper blocks: pose a <= pose b within a point
                fb = 6 * cell_pose[b]
                for i in range(6):
                    for j in range(6):
                        S[fa + i, fb + j] -= Z[a, i, 0] * Z[b, j, 0] + Z[a, i, 1] * Z[b, j, 1] + Z[a, i, 2] * Z[b, j, 2]
        start = end
    for f in range(n_free):
        for i in range(6):
            r[6 * f + i] -= g_pose[f, i]
            for j in range(6):
                S[6 * f + i, 6 * f + j] += U_damped[f, i, j]
    for f in range(n_free):  # the lower blocks mirror the upper ones (the diagonal blocks are symmetric already)
        for g in range(f + 1, n_free):
            for i in range(6):
                for j in range(6):
                    S[6 * g + j, 6 * f + i] = S[6 * f + i, 6 * g + j]
    return S, r, Z, h


@kernel
def _back_substitute(Z, C_inv, cell_point, cell_pose, h, d_pose):
    h = h.copy()
    for c in range(len(Z)):
        p, f = cell_point[c], cell_pose[c]
        for j in range(3):
            total = 0.0
            for i in range(6):
                total += Z[c, i, j] * d_pose[f, i]
            h[p, j] += total
    d_point = np.empty_like(h)
    for p in range(len(h)):  # -C^-T h: (C^-T)[i, k] = C^-1[k, i]
        for i in range(3):
            d_point[p, i] = -(C_inv[p, 0, i] * h[p, 0] + C_inv[p, 1, i] * h[p, 1] + C_inv[p, 2, i] * h[p, 2])
    return d_point
