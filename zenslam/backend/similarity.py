"""The transform between two keyframes from matched map points: Horn's closed form, RANSAC, refinement.

Loop verification (ORB-SLAM's ``Sim3Solver`` and ``Optimizer::OptimizeSim3``) needs the transform
taking points of keyframe 2's camera frame into keyframe 1's: ``p1 = s R p2 + t``. Stereo and RGB-D
maps have a metric scale, so ``s`` is fixed to 1 (a rigid SE(3) transform); monocular maps drift in
scale, so ``s`` is estimated (Sim(3)). One code path serves both: ``with_scale`` only decides
whether the scale is solved for.

- ``horn_alignment``: the least-squares transform of point sets (Horn 1987, unit quaternions: the
  rotation is the eigenvector of the largest eigenvalue of a symmetric 4x4 matrix; the scale the
  least-squares one of p1 ~ s R p2 given R, as ORB-SLAM's).
- ``find_similarity``: RANSAC over minimal sets of 3 matches. A match is an inlier when both
  reprojections -- s R p2 + t into image 1 and its inverse applied to p1 into image 2 -- fall
  within chi2 (9.210, 99% with 2 dof) times the keypoint's level variance and in front of the
  camera. Hypotheses are drawn in batches and evaluated with array operations; the number drawn
  follows the usual adaptive bound, so a run depends only on the generator's seed. The best
  hypothesis is then re-estimated from its inliers while that does not lose inliers.
- ``optimize_similarity``: Levenberg-Marquardt on the reprojection errors of the matches in both
  images with a Huber kernel, outliers (chi2 > 10) dropped after the first pass, as OptimizeSim3.
  It is a 6- or 7-parameter problem over fixed points, small enough for a few lines of numpy: the
  Jacobians are analytic, the update a left perturbation (rotation, translation, log scale).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.errors import ZenslamError
from zenslam.geometry import so3_exp

logger = logging.getLogger(__name__)


class SimilarityError(ZenslamError):
    """Matches handed to the similarity solver are mis-shaped or not finite."""


@dataclass(frozen=True)
class SimilarityRansacConfig:
    """RANSAC of the transform between two keyframes (defaults: ORB-SLAM's loop closing)."""

    min_inliers: int = 20  # matches consistent with the transform for it to be returned (count)
    max_iterations: int = 300  # hypotheses drawn at most (count)
    probability: float = 0.99  # wanted probability of drawing one all-inlier minimal set (0..1)
    # Squared reprojection error over the keypoint's level variance (px^2 / px^2) below which a
    # match is an inlier, in each image: 99% of chi2 with 2 dof.
    chi2_threshold: float = 9.210
    batch: int = 32  # hypotheses evaluated together with array operations (count; speed only)
    refine_rounds: int = 3  # re-estimations of the best hypothesis from its inliers (count)

    def __post_init__(self) -> None:
        if self.min_inliers < 3:
            raise SimilarityError(f"min_inliers={self.min_inliers} must be at least 3 (the minimal set)")
        if not 0.0 < self.probability < 1.0:
            raise SimilarityError(f"probability={self.probability} must lie strictly between 0 and 1")
        if self.max_iterations < 1 or self.batch < 1:
            raise SimilarityError(f"max_iterations={self.max_iterations} and batch={self.batch} must be at least 1")


@dataclass(frozen=True)
class SimilarityOptimizationConfig:
    """Refinement of the transform on the matches (defaults: ORB-SLAM's OptimizeSim3 in loop closing)."""

    # Squared reprojection error over the level variance (unitless) beyond which a match is an
    # outlier in either image; its root is the Huber threshold on the whitened error.
    chi2_threshold: float = 10.0
    robust_iterations: int = 5  # first pass, every match (count)
    refine_iterations: int = 10  # second pass, outliers of the first dropped (count)
    min_inliers: int = 10  # fewer matches left after the first pass: no transform (count)
    step_tolerance: float = 1e-10  # a pass stops when the update's norm falls below this (unitless)


@dataclass(frozen=True)
class SimilarityMatches:
    """Matched points of keyframes 1 and 2, each in its own camera frame, with their keypoints."""

    p1_cam: np.ndarray  # (N, 3) metres, keyframe 1's camera frame (x right, y down, z forward)
    p2_cam: np.ndarray  # (N, 3) metres, keyframe 2's camera frame
    px1: np.ndarray  # (N, 2) keypoint observing the point in image 1, level-0 pixels
    px2: np.ndarray  # (N, 2) keypoint in image 2, level-0 pixels
    sigma2_1: np.ndarray  # (N,) level variance of the keypoint in image 1, px^2 (scale_factor**(2 level))
    sigma2_2: np.ndarray  # (N,) level variance in image 2, px^2
    calibration1: PinholeCalibration
    calibration2: PinholeCalibration

    def __post_init__(self) -> None:
        for name in ("p1_cam", "p2_cam", "px1", "px2", "sigma2_1", "sigma2_2"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        n = len(self.p1_cam)
        expected = {"p1_cam": (n, 3), "p2_cam": (n, 3), "px1": (n, 2), "px2": (n, 2), "sigma2_1": (n,), "sigma2_2": (n,)}
        problems = [f"{k} has shape {np.shape(getattr(self, k))}, expected {v}" for k, v in expected.items() if np.shape(getattr(self, k)) != v]
        if not problems:
            bad = [k for k in expected if not np.isfinite(getattr(self, k)).all()]
            problems += [f"{k} holds non-finite values" for k in bad]
            if not ((self.sigma2_1 > 0).all() and (self.sigma2_2 > 0).all()):
                problems.append("level variances must be positive")
        if problems:
            raise SimilarityError("invalid similarity matches: " + "; ".join(problems) + "; build them from matched map points")

    def __len__(self) -> int:
        return len(self.p1_cam)


@dataclass(frozen=True)
class SimilarityEstimate:
    """``p1 = scale * R @ p2 + t`` with R, t the blocks of ``T_12``, and the matches it explains."""

    T_12: np.ndarray  # (4, 4): rotation R and translation t (metres of frame 1); rigid when scale == 1
    scale: float  # s (1.0 for the rigid SE(3) case)
    inliers: np.ndarray  # (N,) bool
    iterations: int  # RANSAC hypotheses drawn, or optimisation iterations run

    @property
    def n_inliers(self) -> int:
        """Number of inlier matches."""
        return int(np.count_nonzero(self.inliers))

    @property
    def S_12(self) -> np.ndarray:
        """The similarity as one (4, 4) matrix [[s R, t], [0, 1]] acting on homogeneous points of frame 2."""
        S = self.T_12.copy()
        S[:3, :3] *= self.scale
        return S

    def transform(self, p2: np.ndarray) -> np.ndarray:
        """Points (M, 3) of frame 2 in frame 1."""
        return apply_similarity(self.T_12[:3, :3], self.T_12[:3, 3], self.scale, p2)


def apply_similarity(R: np.ndarray, t: np.ndarray, s: float, p: np.ndarray) -> np.ndarray:
    """s R p + t for points (M, 3)."""
    return s * np.asarray(p, dtype=float).reshape(-1, 3) @ np.asarray(R).T + np.asarray(t).reshape(3)


def horn_alignment(p1: np.ndarray, p2: np.ndarray, with_scale: bool) -> tuple[np.ndarray, float]:
    """The (T_12, s) minimising sum |p1 - (s R p2 + t)|^2 over point sets (N, 3), N >= 3.

    ``with_scale`` False fixes s = 1 (rigid). Raises SimilarityError for fewer than 3 pairs; a
    degenerate set (collinear points) gives one of the equally good rotations.
    """
    p1, p2 = np.asarray(p1, dtype=float).reshape(-1, 3), np.asarray(p2, dtype=float).reshape(-1, 3)
    if len(p1) != len(p2) or len(p1) < 3:
        raise SimilarityError(f"Horn's alignment needs two sets of at least 3 paired points, got {len(p1)} and {len(p2)}")
    R, t, s = _horn_batch(p1[None], p2[None], with_scale)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R[0], t[0]
    return T, float(s[0])


def _horn_batch(p1: np.ndarray, p2: np.ndarray, with_scale: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Horn's closed form for H problems at once: p1, p2 (H, k, 3) -> R (H, 3, 3), t (H, 3), s (H,)."""
    c1, c2 = p1.mean(axis=1), p2.mean(axis=1)
    q1, q2 = p1 - c1[:, None], p2 - c2[:, None]
    M = np.einsum("hka,hkb->hab", q2, q1)  # sum over points of q2 q1^T
    xx, xy, xz = M[:, 0, 0], M[:, 0, 1], M[:, 0, 2]
    yx, yy, yz = M[:, 1, 0], M[:, 1, 1], M[:, 1, 2]
    zx, zy, zz = M[:, 2, 0], M[:, 2, 1], M[:, 2, 2]
    N = np.stack([
        np.stack([xx + yy + zz, yz - zy, zx - xz, xy - yx], -1),
        np.stack([yz - zy, xx - yy - zz, xy + yx, zx + xz], -1),
        np.stack([zx - xz, xy + yx, -xx + yy - zz, yz + zy], -1),
        np.stack([xy - yx, zx + xz, yz + zy, -xx - yy + zz], -1),
    ], axis=1)  # fmt: skip
    _, vectors = np.linalg.eigh(N)
    R = _quat_wxyz_to_R(vectors[:, :, -1])  # eigenvector of the largest eigenvalue: the rotation 2 -> 1
    rotated = np.einsum("hab,hkb->hka", R, q2)
    if with_scale:
        den = np.einsum("hka,hka->h", rotated, rotated)
        s = np.einsum("hka,hka->h", q1, rotated) / np.where(den > 1e-300, den, 1.0)
        s = np.where(den > 1e-300, s, 1.0)
    else:
        s = np.ones(len(p1))
    t = c1 - s[:, None] * np.einsum("hab,hb->ha", R, c2)
    return R, t, s


def _quat_wxyz_to_R(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (H, 3, 3) of unit quaternions (H, 4) ordered (w, x, y, z)."""
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)  # fmt: skip


def _project(calibration: PinholeCalibration, p_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (..., 2) and depth z (...) of camera-frame points (..., 3)."""
    z = p_cam[..., 2]
    inv_z = 1.0 / np.where(np.abs(z) > 1e-12, z, 1e-12)
    u = calibration.fx * p_cam[..., 0] * inv_z + calibration.cx
    v = calibration.fy * p_cam[..., 1] * inv_z + calibration.cy
    return np.stack([u, v], -1), z


def _chi2_both(m: SimilarityMatches, R: np.ndarray, t: np.ndarray, s: np.ndarray, rows: np.ndarray | None = None):
    """Level-normalised squared reprojection errors of H transforms (R (H,3,3), t (H,3), s (H,)) in
    image 1 and image 2, (H, N) each; a point behind a camera gets inf."""
    sel = slice(None) if rows is None else rows
    p1, p2 = m.p1_cam[sel], m.p2_cam[sel]
    q1 = s[:, None, None] * np.einsum("hab,nb->hna", R, p2) + t[:, None]  # p2 mapped into frame 1
    q2 = np.einsum("hba,hnb->hna", R, p1[None] - t[:, None]) / s[:, None, None]  # p1 mapped into frame 2
    uv1, z1 = _project(m.calibration1, q1)
    uv2, z2 = _project(m.calibration2, q2)
    chi1 = np.sum((uv1 - m.px1[sel]) ** 2, axis=-1) / m.sigma2_1[sel]
    chi2 = np.sum((uv2 - m.px2[sel]) ** 2, axis=-1) / m.sigma2_2[sel]
    return np.where(z1 > 0, chi1, np.inf), np.where(z2 > 0, chi2, np.inf)


def _inliers(m: SimilarityMatches, R, t, s, threshold: float) -> np.ndarray:
    """(H, N) bool: both reprojections within ``threshold`` (level-normalised chi2)."""
    chi1, chi2 = _chi2_both(m, R, t, s)
    return (chi1 < threshold) & (chi2 < threshold)


def _needed_iterations(n_inliers: int, n: int, probability: float) -> float:
    """Hypotheses needed to draw one all-inlier minimal set with ``probability`` at inlier ratio n_inliers/n."""
    ratio = n_inliers / n
    if ratio >= 1.0:
        return 1.0
    if ratio <= 0.0:
        return math.inf
    return math.log(1.0 - probability) / math.log(1.0 - ratio**3)


def find_similarity(
    matches: SimilarityMatches, with_scale: bool, config: SimilarityRansacConfig, rng: np.random.Generator
) -> SimilarityEstimate | None:
    """RANSAC of ``p1 = s R p2 + t`` over the matches (see module docstring); None when no hypothesis
    gathers ``config.min_inliers`` inliers. ``rng`` draws the minimal sets (seed it for repeatable runs)."""
    n = len(matches)
    if n < max(config.min_inliers, 3):
        return None
    best_count, best, drawn = -1, None, 0
    while drawn < min(config.max_iterations, _needed_iterations(max(best_count, 0), n, config.probability)):
        h = min(config.batch, config.max_iterations - drawn)
        sets = np.argpartition(rng.random((h, n)), 2, axis=1)[:, :3]  # 3 distinct matches per hypothesis
        R, t, s = _horn_batch(matches.p1_cam[sets], matches.p2_cam[sets], with_scale)
        counts = _inliers(matches, R, t, s, config.chi2_threshold).sum(axis=1)
        k = int(np.argmax(counts))
        drawn += h
        if counts[k] > best_count:
            best_count, best = int(counts[k]), (R[k], t[k], float(s[k]))
    R, t, s = best
    inliers = _inliers(matches, R[None], t[None], np.array([s]), config.chi2_threshold)[0]
    for _ in range(config.refine_rounds):
        if inliers.sum() < 3:
            break
        T, s_new = horn_alignment(matches.p1_cam[inliers], matches.p2_cam[inliers], with_scale)
        refined = _inliers(matches, T[None, :3, :3], T[None, :3, 3], np.array([s_new]), config.chi2_threshold)[0]
        if refined.sum() < inliers.sum():
            break
        changed = not np.array_equal(refined, inliers)
        R, t, s, inliers = T[:3, :3], T[:3, 3], s_new, refined
        if not changed:
            break
    if inliers.sum() < config.min_inliers:
        logger.debug("similarity RANSAC: best %d of %d inliers after %d hypotheses", int(inliers.sum()), n, drawn)
        return None
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return SimilarityEstimate(T, float(s), inliers, drawn)


def optimize_similarity(
    matches: SimilarityMatches,
    T_12: np.ndarray,
    scale: float,
    with_scale: bool,
    config: SimilarityOptimizationConfig,
) -> SimilarityEstimate | None:
    """Refine ``p1 = s R p2 + t`` (start: R, t of ``T_12`` and ``scale``) on the reprojection errors of
    every match in both images, as ORB-SLAM's OptimizeSim3: a Huber-weighted pass, matches beyond
    ``chi2_threshold`` in either image dropped, a second pass on the rest. Returns the refined
    transform and its inliers, or None when fewer than ``min_inliers`` survive the first pass."""
    R = np.asarray(T_12, dtype=float)[:3, :3].copy()
    t = np.asarray(T_12, dtype=float)[:3, 3].copy()
    s = float(scale) if with_scale else 1.0
    active = np.ones(len(matches), dtype=bool)
    total = 0
    for iterations, drop_after in ((config.robust_iterations, True), (config.refine_iterations, False)):
        R, t, s, run = _levenberg_marquardt(matches, np.flatnonzero(active), R, t, s, with_scale, iterations, config)
        total += run
        if drop_after:
            active &= _inliers(matches, R[None], t[None], np.array([s]), config.chi2_threshold)[0]
            if active.sum() < config.min_inliers:
                return None
    inliers = _inliers(matches, R[None], t[None], np.array([s]), config.chi2_threshold)[0]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return SimilarityEstimate(T, s, inliers, total)


def _levenberg_marquardt(m, rows, R, t, s, with_scale, iterations, config):
    """Huber-weighted LM on the matches ``rows``; returns R, t, s and the iterations run."""
    huber = math.sqrt(config.chi2_threshold)
    cost = _robust_cost(m, rows, R, t, s, huber)
    lam, run = 1e-3, 0
    for _ in range(iterations):
        J, r, w = _linearize(m, rows, R, t, s, huber)
        if not with_scale:
            J = J[:, :6]
        JtW = J.T * w
        H, g = JtW @ J, JtW @ r
        run += 1
        while True:
            delta = np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), -g)
            R_new, t_new, s_new = _retract(R, t, s, delta if with_scale else np.append(delta, 0.0))
            new_cost = _robust_cost(m, rows, R_new, t_new, s_new, huber)
            if new_cost <= cost:
                R, t, s, cost, lam = R_new, t_new, s_new, new_cost, max(lam / 10.0, 1e-9)
                break
            lam *= 10.0
            if lam > 1e8:
                return R, t, s, run
        if np.linalg.norm(delta) < config.step_tolerance:
            break
    return R, t, s, run


def _retract(R, t, s, delta):
    """exp(delta) composed on the left: delta = (rotation (3), translation (3) metres, log scale)."""
    dR, e = so3_exp(delta[:3]), math.exp(delta[6])
    return dR @ R, e * (dR @ t) + delta[3:6], s * e


def _residuals(m: SimilarityMatches, rows, R, t, s):
    """Whitened residuals (n, 2) in image 1 and image 2 and the mapped points q1, q2 (n, 3)."""
    p1, p2 = m.p1_cam[rows], m.p2_cam[rows]
    q1 = s * p2 @ R.T + t
    q2 = (p1 - t) @ R / s
    uv1, _ = _project(m.calibration1, q1)
    uv2, _ = _project(m.calibration2, q2)
    r1 = (m.px1[rows] - uv1) / np.sqrt(m.sigma2_1[rows])[:, None]
    r2 = (m.px2[rows] - uv2) / np.sqrt(m.sigma2_2[rows])[:, None]
    return r1, r2, q1, q2


def _robust_cost(m, rows, R, t, s, huber: float) -> float:
    """Sum of Huber costs of the whitened errors in both images (a point behind a camera costs inf)."""
    r1, r2, q1, q2 = _residuals(m, rows, R, t, s)
    if (q1[:, 2] <= 0).any() or (q2[:, 2] <= 0).any():
        return math.inf
    e = np.concatenate([np.linalg.norm(r1, axis=1), np.linalg.norm(r2, axis=1)])
    return float(np.sum(np.where(e <= huber, 0.5 * e**2, huber * (e - 0.5 * huber))))


def _linearize(m: SimilarityMatches, rows, R, t, s, huber: float):
    """Jacobian (4n, 7) of the stacked whitened residuals w.r.t. the left perturbation, residuals
    (4n,), and Huber weights (4n,) (one per match and image, repeated over u and v)."""
    r1, r2, q1, q2 = _residuals(m, rows, R, t, s)
    n = len(rows)
    # d q1 / d(rot, trans, log scale): q1 = E(S(p2)) with E the perturbation.
    dq1 = np.zeros((n, 3, 7))
    dq1[:, :, :3] = -_skew_batch(q1)
    dq1[:, :, 3:6] = np.eye(3)
    dq1[:, :, 6] = q1
    # d q2: q2 = S^-1(E^-1(p1)), E^-1(p) ~ p - w x p - v - sigma p, S^-1 linear part A = R^T / s.
    A = R.T / s
    p1 = m.p1_cam[rows]
    dq2 = np.zeros((n, 3, 7))
    dq2[:, :, :3] = np.einsum("ab,nbc->nac", A, _skew_batch(p1))
    dq2[:, :, 3:6] = -A
    dq2[:, :, 6] = -(p1 @ A.T)
    J1 = -np.einsum("nij,njk->nik", _projection_jacobian(m.calibration1, q1), dq1) / np.sqrt(m.sigma2_1[rows])[:, None, None]
    J2 = -np.einsum("nij,njk->nik", _projection_jacobian(m.calibration2, q2), dq2) / np.sqrt(m.sigma2_2[rows])[:, None, None]
    e1, e2 = np.linalg.norm(r1, axis=1), np.linalg.norm(r2, axis=1)
    w1 = np.where(e1 <= huber, 1.0, huber / np.maximum(e1, 1e-300))
    w2 = np.where(e2 <= huber, 1.0, huber / np.maximum(e2, 1e-300))
    J = np.concatenate([J1.reshape(-1, 7), J2.reshape(-1, 7)])
    r = np.concatenate([r1.reshape(-1), r2.reshape(-1)])
    w = np.concatenate([np.repeat(w1, 2), np.repeat(w2, 2)])
    return J, r, w


def _skew_batch(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices (n, 3, 3) of vectors (n, 3)."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -v[:, 2], v[:, 1]
    out[:, 1, 0], out[:, 1, 2] = v[:, 2], -v[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -v[:, 1], v[:, 0]
    return out


def _projection_jacobian(c: PinholeCalibration, q: np.ndarray) -> np.ndarray:
    """d pixel / d point (n, 2, 3) of the pinhole projection at camera-frame points q (n, 3)."""
    x, y, z = q.T
    inv_z = 1.0 / np.where(np.abs(z) > 1e-12, z, 1e-12)
    J = np.zeros((len(q), 2, 3))
    J[:, 0, 0] = c.fx * inv_z
    J[:, 0, 2] = -c.fx * x * inv_z**2
    J[:, 1, 1] = c.fy * inv_z
    J[:, 1, 2] = -c.fy * y * inv_z**2
    return J
