"""Refinement of a relative camera motion by the Sampson epipolar error of all matches.

A motion decomposed from a linearly fitted fundamental matrix can be several degrees off in
translation direction. The Sampson distance is the first-order geometric error of a match to the
epipolar geometry of a motion, so minimising it over the 5 degrees of freedom (rotation,
translation direction) comes close to two-view bundle adjustment without the points.

Every match takes part, weighted by Tukey's biweight: the inliers of the linear model were chosen
by their agreement with that model, and refining on them alone keeps its error. Tukey's kernel
ignores gross outliers entirely and lets matches re-enter as the motion improves. Solved by
Levenberg-Marquardt with the Jacobian by forward differences (5 parameters, a cheap residual).
"""

from __future__ import annotations

import math

import numpy as np

from zenslam.geometry import skew, so3_exp

# Tukey's kernel ends at the bound of ORB-SLAM's F score, sqrt(5.991) sigma: a wider kernel lets
# the few outliers that fall near an epipolar line pull the weakly observed translation direction.
_TUKEY_C = math.sqrt(5.991)
_STEP = 1e-7  # forward-difference step (radians and unit-direction components)
_CONVERGED = 1e-10  # relative cost decrease below which the refinement stops


def refine_motion(
    R: np.ndarray, t: np.ndarray, x_ref: np.ndarray, x_cur: np.ndarray, K: np.ndarray, sigma2: np.ndarray, iterations: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(R_cur_ref, t_cur_ref)`` refined from the given ones over matches (N, 2) px, outliers
    included, with variances ``sigma2`` (N,) px^2; ``t`` keeps unit norm. The start must be
    within the kernel's reach of the truth (a few degrees). At most ``iterations`` accepted steps."""
    K_inv = np.linalg.inv(K)
    xh_ref = np.column_stack([x_ref, np.ones(len(x_ref))])
    xh_cur = np.column_stack([x_cur, np.ones(len(x_cur))])
    inv_sigma = 1.0 / np.sqrt(sigma2)

    def residuals(R_: np.ndarray, t_: np.ndarray) -> np.ndarray:
        F = K_inv.T @ skew(t_) @ R_ @ K_inv
        lines_cur = xh_ref @ F.T
        lines_ref = xh_cur @ F
        num = np.einsum("ni,ni->n", xh_cur, lines_cur)
        den = np.sqrt(lines_cur[:, 0] ** 2 + lines_cur[:, 1] ** 2 + lines_ref[:, 0] ** 2 + lines_ref[:, 1] ** 2)
        return num / den * inv_sigma

    def moved(delta: np.ndarray, R_: np.ndarray, t_: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t_new = t_ + basis @ delta[3:]
        return so3_exp(delta[:3]) @ R_, t_new / np.linalg.norm(t_new)

    r = residuals(R, t)
    cost = _tukey_cost(r)
    damping = 1e-3
    for _ in range(iterations):
        basis = np.linalg.svd(t[None, :])[2][1:].T  # (3, 2): the tangent plane of the unit sphere at t
        J = np.empty((len(r), 5))
        for k in range(5):
            delta = np.zeros(5)
            delta[k] = _STEP
            J[:, k] = (residuals(*moved(delta, R, t, basis)) - r) / _STEP
        w = _tukey_weights(r)
        H = J.T @ (w[:, None] * J)
        g = J.T @ (w * r)
        improved = False
        while damping < 1e8:
            step = -np.linalg.solve(H + damping * np.diag(np.diag(H) + 1e-12), g)
            R_new, t_new = moved(step, R, t, basis)
            r_new = residuals(R_new, t_new)
            cost_new = _tukey_cost(r_new)
            if cost_new < cost:
                improved = True
                break
            damping *= 10.0
        if not improved:
            break
        converged = cost - cost_new < _CONVERGED * cost
        R, t, r, cost = R_new, t_new, r_new, cost_new
        damping = max(damping / 10.0, 1e-9)
        if converged:
            break
    return R, t


def _tukey_weights(r: np.ndarray) -> np.ndarray:
    u = (r / _TUKEY_C) ** 2
    return np.where(u < 1.0, (1.0 - u) ** 2, 0.0)


def _tukey_cost(r: np.ndarray) -> float:
    u = np.minimum((r / _TUKEY_C) ** 2, 1.0)
    return float((_TUKEY_C**2 / 6.0 * (1.0 - (1.0 - u) ** 3)).sum())
