"""The normal equations of pose-only optimisation, from one compiled pass over the observations.

Each Levenberg-Marquardt iteration of ``pose_optimizer`` needs, at the current pose, the robust
cost and the 6x6 system H = J^T W J, g = J^T W r of a few hundred observations. In numpy that
was a dozen passes building (N, 3) and (N, 3, 6) temporaries for a 6x6 answer, and most of a
frame's pose optimisation; here each observation is projected, weighed and summed into H and g
in one loop.

Sums run over the observations in order, in IEEE double arithmetic (no fastmath: LLVM neither
reorders nor contracts them), so the answer has the same bits on every x86-64 target numba may
compile for.
"""

from __future__ import annotations

import math

import numpy as np

from zenslam.compiled import kernel


@kernel
def normal_equations(
    T: np.ndarray,
    p_world: np.ndarray,
    obs: np.ndarray,
    row_mask: np.ndarray,
    inv_sigma2: np.ndarray,
    delta2: np.ndarray,
    information: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    bf: float,
    robust: bool,
    min_depth_m: float,
) -> tuple[float, np.ndarray, np.ndarray]:
    """(cost, H (6, 6), g (6,)) of observations ``obs`` (N, 3) of points ``p_world`` (N, 3) at pose ``T``.

    ``T`` maps world points into the camera; the step is the left perturbation T <- exp(xi) T with
    xi = (omega rad, upsilon m). Residuals are predicted - observed (u, v, u_right) times
    ``row_mask`` (0 for a mono observation's u_right); W is ``information[i]`` (3, 3) when
    ``information`` has one matrix per observation, else ``inv_sigma2[i]`` times the identity. With
    ``robust``, Huber weights on the chi-square (g2o's: rho(s) = s inside ``delta2``, 2 delta sqrt(s)
    - delta^2 outside). An observation at or behind ``min_depth_m`` costs its ``delta2`` and adds
    nothing to H and g, so leaving the frustum is no gain.
    """
    n = p_world.shape[0]
    weighted = information.shape[0] == n and n > 0
    H = np.zeros((6, 6))
    g = np.zeros(6)
    J = np.empty((3, 6))
    Jw = np.empty((3, 6))
    r = np.empty(3)
    cost = 0.0
    for i in range(n):
        px, py, pz = p_world[i, 0], p_world[i, 1], p_world[i, 2]
        x = T[0, 0] * px + T[0, 1] * py + T[0, 2] * pz + T[0, 3]
        y = T[1, 0] * px + T[1, 1] * py + T[1, 2] * pz + T[1, 3]
        z = T[2, 0] * px + T[2, 1] * py + T[2, 2] * pz + T[2, 3]
        inv_z = 1.0 / (z if abs(z) > 1e-12 else 1e-12)
        u = fx * x * inv_z + cx
        r[0] = (u - obs[i, 0]) * row_mask[i, 0]
        r[1] = (fy * y * inv_z + cy - obs[i, 1]) * row_mask[i, 1]
        r[2] = (u - bf * inv_z - obs[i, 2]) * row_mask[i, 2]
        if weighted:
            chi2 = 0.0
            for k in range(3):
                for m in range(3):
                    chi2 += r[k] * information[i, k, m] * r[m]
        else:
            chi2 = inv_sigma2[i] * (r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        d2 = delta2[i]
        if robust:
            root = math.sqrt(max(chi2, d2))
            delta = math.sqrt(d2)
            rho = 2.0 * delta * root - d2 if chi2 > d2 else chi2
            weight = delta / root
        else:
            rho = chi2
            weight = 1.0
        if not z > min_depth_m:
            cost += d2
            continue
        cost += rho
        # d(u, v, u_right)/d(p_cam) @ [-[p_cam]x | I], written out as g2o's EdgeStereoSE3ProjectXYZOnlyPose.
        xz, yz = x * inv_z, y * inv_z
        J[0, 0] = -fx * xz * yz
        J[0, 1] = fx * (1.0 + xz * xz)
        J[0, 2] = -fx * yz
        J[0, 3] = fx * inv_z
        J[0, 4] = 0.0
        J[0, 5] = -fx * xz * inv_z
        J[1, 0] = -fy * (1.0 + yz * yz)
        J[1, 1] = fy * xz * yz
        J[1, 2] = fy * xz
        J[1, 3] = 0.0
        J[1, 4] = fy * inv_z
        J[1, 5] = -fy * yz * inv_z
        # u_right = u - bf / z adds bf / z^2 * d(z)/d(xi), with d(z)/d(xi) = (y, -x, 0, 0, 0, 1).
        b = bf * inv_z * inv_z
        for a in range(6):
            J[2, a] = J[0, a]
        J[2, 0] += b * y
        J[2, 1] -= b * x
        J[2, 5] += b
        if weighted:
            for k in range(3):
                for a in range(6):
                    s = 0.0
                    for m in range(3):
                        s += information[i, k, m] * weight * (J[m, a] * row_mask[i, m])
                    Jw[k, a] = s
        else:
            for k in range(3):
                w = weight * inv_sigma2[i] * row_mask[i, k]
                for a in range(6):
                    Jw[k, a] = J[k, a] * w
        for a in range(6):
            g[a] += Jw[0, a] * r[0] + Jw[1, a] * r[1] + Jw[2, a] * r[2]
            for c in range(a, 6):
                H[a, c] += Jw[0, a] * J[0, c] + Jw[1, a] * J[1, c] + Jw[2, a] * J[2, c]
    for a in range(6):
        for c in range(a):
            H[a, c] = H[c, a]
    return cost, H, g
