"""Monocular initialisation from two views: relative pose and first points, as ORB-SLAM's ``Initializer``.

A homography and a fundamental matrix are fitted in parallel on the same RANSAC sample sets
(``two_view_models``). The ratio ``R_H = S_H / (S_H + S_F)`` of their scores chooses the model: a
planar scene or a low-parallax view is explained by H, a general scene by F. The chosen model is
decomposed into candidate motions (8 from H by Faugeras' method, 4 from E = K^T F K), every
candidate triangulates the model's inliers, and the candidate with the most points in front of
both cameras and reprojecting within 2 sigma wins, unless it is not clearly better than the next,
sees the points with too little parallax, or explains too few of the inliers. Then the views are
refused and the caller tries the next frame: pure rotation or no motion never makes a map.

Two steps go beyond ORB-SLAM, which leaves accuracy to the bundle adjustment that follows: the
chosen model is refitted by least squares on its inliers before it is decomposed, and an accepted
motion from F is refined on the Sampson error of all matches (``two_view_refinement``). The
decision to accept or refuse is ORB-SLAM's, taken before the motion is refined.

``sigma_px`` is ORB-SLAM's sigma: a transfer or epipolar error, which carries the noise of both
keypoints, is compared with it. When the keypoints' own noise approaches it, F's 1-dof errors
outscore H's 2-dof ones and R_H of a planar scene falls towards the 0.45 threshold.

Inputs are plain arrays (undistorted level-0 pixels of matched keypoints), so the module knows
nothing of frames or trackers. The translation has unit norm; the map's scale is the caller's.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from zenslam.errors import ConfigError
from zenslam.frontend.two_view_models import (
    SAMPLE_SIZE,
    ModelFit,
    adjugate,
    draw_sample_sets,
    find_fundamental,
    find_homography,
    refine_fundamental,
    refine_homography,
)
from zenslam.frontend.two_view_refinement import refine_motion
from zenslam.geometry import make_T

logger = logging.getLogger(__name__)

Model = Literal["homography", "fundamental"]
RefusalReason = Literal["too_few_matches", "no_model", "low_parallax", "degenerate", "ambiguous", "too_few_triangulated"]

# A point seen with less parallax than this (cosine of the angle, ~0.36 deg) is too far to place:
# its depth may come out negative, so it is exempt from the depth test, counts as explained by the
# motion, but is not returned as triangulated (ORB-SLAM's CheckRT).
_FAR_COS_PARALLAX = 0.99998
# Singular values of K^-1 H K closer than this ratio leave Faugeras' decomposition undefined.
_DISTINCT_SINGULAR_RATIO = 1.00001


@dataclass(frozen=True)
class TwoViewConfig:
    """Two-view initialisation settings; defaults are ORB-SLAM's."""

    ransac_iterations: int = 200  # 8-point hypotheses per model (count)
    sigma_px: float = 1.0  # standard deviation of a level-0 match's error per coordinate (px), as ORB-SLAM scores it
    min_matches: int = 100  # matches needed to try at all (count; ORB-SLAM's monocular tracker asks 100)
    homography_ratio_threshold: float = 0.45  # R_H = S_H/(S_H+S_F) above this reconstructs from H (fraction)
    min_parallax_deg: float = 1.0  # parallax the points must reach (degrees), measured at parallax_rank
    parallax_rank: int = 50  # the parallax is that of the (rank+1)-th largest-parallax point (0-based index, count)
    min_triangulated: int = 50  # points the winning motion must explain, at least (count)
    min_triangulated_fraction: float = 0.9  # ... and at least this fraction of the model's inliers
    reprojection_chi2: float = 4.0  # squared reprojection error / sigma^2 allowed for a triangulated point
    homography_ambiguity_ratio: float = 0.75  # H: refuse when the second-best motion explains above this fraction of the best's points
    fundamental_ambiguity_ratio: float = 0.7  # F: the same, with ORB-SLAM's F value
    refine_rounds: int = 3  # least-squares refits of the chosen model on its inliers (count; 0 is ORB-SLAM)
    refine_iterations: int = 20  # Levenberg-Marquardt steps on the winning motion's Sampson error (count; 0 is ORB-SLAM)
    seed: int = 0  # seed of the RANSAC sample sets

    def __post_init__(self) -> None:
        problems = []
        if self.ransac_iterations < 1:
            problems.append(f"ransac_iterations={self.ransac_iterations} must be at least 1")
        if not (math.isfinite(self.sigma_px) and self.sigma_px > 0.0):
            problems.append(f"sigma_px={self.sigma_px} must be a positive number of pixels")
        if self.min_matches < SAMPLE_SIZE:
            problems.append(f"min_matches={self.min_matches} must be at least {SAMPLE_SIZE}")
        for name in ("homography_ratio_threshold", "min_triangulated_fraction", "homography_ambiguity_ratio", "fundamental_ambiguity_ratio"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                problems.append(f"{name}={getattr(self, name)} must be a fraction in [0, 1]")
        if not 0.0 <= self.min_parallax_deg < 90.0:
            problems.append(f"min_parallax_deg={self.min_parallax_deg} must be in [0, 90) degrees")
        if self.parallax_rank < 0 or self.min_triangulated < 0:
            problems.append(f"parallax_rank={self.parallax_rank} and min_triangulated={self.min_triangulated} must be >= 0")
        if not self.reprojection_chi2 > 0.0:
            problems.append(f"reprojection_chi2={self.reprojection_chi2} must be positive")
        if problems:
            raise ConfigError("invalid two-view initialisation configuration: " + "; ".join(problems))


@dataclass(frozen=True)
class TwoViewResult:
    """An accepted initialisation: the relative pose and the points it triangulated."""

    T_cur_ref: np.ndarray  # (4, 4) maps reference-camera points into the current camera; |t| = 1
    p_ref: np.ndarray  # (N, 3) triangulated points in the reference camera frame, rows in the order of `triangulated`
    triangulated: np.ndarray  # (M,) bool per input match: its point is in p_ref
    inliers: np.ndarray  # (M,) bool per input match: inlier of the chosen model's RANSAC
    model: Model
    score_ratio: float  # R_H = S_H / (S_H + S_F)
    parallax_deg: float  # parallax of the (parallax_rank+1)-th largest-parallax point (degrees)


@dataclass(frozen=True)
class TwoViewRefusal:
    """Why two views did not initialise; the caller tries again with a later frame."""

    reason: RefusalReason
    message: str  # one line for logs and status, with the figures that decided it
    model: Model | None = None
    score_ratio: float = math.nan
    parallax_deg: float = math.nan
    n_inliers: int = 0  # inliers of the chosen model
    n_good: int = 0  # points the best motion explains
    n_good_second: int = 0  # points the second-best motion explains


@dataclass(frozen=True)
class _Candidate:
    """One candidate motion and the inliers it explains (ORB-SLAM's CheckRT)."""

    R: np.ndarray  # (3, 3) R_cur_ref
    t: np.ndarray  # (3,) t_cur_ref, unit norm
    good: np.ndarray  # (N,) bool over the inliers: finite, in front (unless far), reprojects within threshold
    triangulated: np.ndarray  # (N,) bool: good and not far
    p_ref: np.ndarray  # (N, 3)
    parallax_deg: float

    @property
    def n_good(self) -> int:
        return int(np.count_nonzero(self.good))


def initialize_two_view(
    x_ref: np.ndarray,
    x_cur: np.ndarray,
    K: np.ndarray,
    level_sigma2: np.ndarray | None = None,
    config: TwoViewConfig | None = None,
) -> TwoViewResult | TwoViewRefusal:
    """Relative pose and points of M matches between a reference and a current view.

    ``x_ref``, ``x_cur`` (M, 2) are undistorted level-0 pixel positions of the matched keypoints,
    ``K`` the 3x3 intrinsics. ``level_sigma2`` (M,) px^2 replaces ``sigma_px**2`` per match (the
    ``level_sigma2`` of the keypoints' pyramid level, as ORB-SLAM's unit sigma scales with it).
    The same inputs and seed always give the same bits.
    """
    config = config or TwoViewConfig()
    x_ref, x_cur, K, sigma2 = _checked_inputs(x_ref, x_cur, K, level_sigma2, config)
    if len(x_ref) < config.min_matches:
        return TwoViewRefusal("too_few_matches", f"{len(x_ref)} matches, {config.min_matches} needed")
    chosen = _choose_model(x_ref, x_cur, K, sigma2, config)
    if isinstance(chosen, TwoViewRefusal):
        return chosen
    model, ratio, fit, motions = chosen
    inl = fit.inliers
    n_inliers = int(np.count_nonzero(inl))
    x_ref_in, x_cur_in, th2_in = x_ref[inl], x_cur[inl], sigma2[inl] * config.reprojection_chi2
    checked = _check_motions(motions, x_ref_in, x_cur_in, K, th2_in, config.parallax_rank)
    order = np.argsort([-c.n_good for c in checked], kind="stable")
    best = checked[int(order[0])]
    n_second = checked[int(order[1])].n_good if len(order) > 1 else 0
    refusal = _refusal(best, n_second, n_inliers, model, ratio, config)
    if refusal is not None:
        return refusal
    if model == "fundamental" and config.refine_iterations > 0:
        # Only F's motion is refined: where H wins, the scene is (nearly) planar, its epipolar
        # error nearly degenerate, and H's motion the better one.
        R, t = refine_motion(best.R, best.t, x_ref, x_cur, K, sigma2, config.refine_iterations)
        refined = _check_motions([(R, t)], x_ref_in, x_cur_in, K, th2_in, config.parallax_rank)[0]
        if _refusal(refined, 0, n_inliers, model, ratio, config) is None:
            best = refined
    logger.debug("two-view initialisation from the %s (R_H %.2f): %d of %d inliers, parallax %.2f deg", model, ratio, best.n_good, n_inliers, best.parallax_deg)
    triangulated = np.zeros(len(x_ref), dtype=bool)
    triangulated[np.flatnonzero(inl)[best.triangulated]] = True
    return TwoViewResult(
        T_cur_ref=make_T(best.R, best.t),
        p_ref=best.p_ref[best.triangulated],
        triangulated=triangulated,
        inliers=inl.copy(),
        model=model,
        score_ratio=ratio,
        parallax_deg=best.parallax_deg,
    )


def _choose_model(
    x_ref: np.ndarray, x_cur: np.ndarray, K: np.ndarray, sigma2: np.ndarray, config: TwoViewConfig
) -> tuple[Model, float, ModelFit, list[tuple[np.ndarray, np.ndarray]]] | TwoViewRefusal:
    """H and F by RANSAC on shared sample sets, the one R_H picks refitted on its inliers, and its
    candidate motions; or why there are none."""
    sets = draw_sample_sets(len(x_ref), config.ransac_iterations, np.random.default_rng(config.seed))
    inv_sigma2 = 1.0 / sigma2
    fit_h = find_homography(x_ref, x_cur, sets, inv_sigma2)
    fit_f = find_fundamental(x_ref, x_cur, sets, inv_sigma2)
    s_h = fit_h.score if fit_h else 0.0
    s_f = fit_f.score if fit_f else 0.0
    if s_h + s_f <= 0.0:
        return TwoViewRefusal("no_model", f"no homography or fundamental matrix explains any of {len(x_ref)} matches")
    ratio = s_h / (s_h + s_f)
    if ratio > config.homography_ratio_threshold:
        assert fit_h is not None
        fit = refine_homography(x_ref, x_cur, fit_h, inv_sigma2, config.refine_rounds)
        motions = _homography_motions(fit.matrix, K)
        if not motions:
            reason, message = _degenerate_reason(fit.matrix, K)
            return TwoViewRefusal(reason, message, model="homography", score_ratio=ratio, n_inliers=int(np.count_nonzero(fit.inliers)))
        return "homography", ratio, fit, motions
    assert fit_f is not None
    fit = refine_fundamental(x_ref, x_cur, fit_f, inv_sigma2, config.refine_rounds)
    return "fundamental", ratio, fit, _essential_motions(K.T @ fit.matrix @ K)


def _refusal(best: _Candidate, n_second: int, n_inliers: int, model: Model, ratio: float, config: TwoViewConfig) -> TwoViewRefusal | None:
    """Why the best candidate motion may not initialise, or None when it may. ORB-SLAM's rules,
    with the small differences between its H and F branches (> against >=) made one rule; too
    little parallax is reported first, as it is what the caller waits out."""
    n_good = best.n_good
    ambiguity = config.homography_ambiguity_ratio if model == "homography" else config.fundamental_ambiguity_ratio
    needed = max(config.min_triangulated, int(config.min_triangulated_fraction * n_inliers))
    figures = dict(model=model, score_ratio=ratio, parallax_deg=best.parallax_deg, n_inliers=n_inliers, n_good=n_good, n_good_second=n_second)
    summary = f"{model}, R_H {ratio:.2f}: best motion explains {n_good} of {n_inliers} inliers (second {n_second}), parallax {best.parallax_deg:.2f} deg"
    if n_good > 0 and best.parallax_deg < config.min_parallax_deg:
        return TwoViewRefusal("low_parallax", f"{summary}; {config.min_parallax_deg} deg needed", **figures)
    if n_second > ambiguity * n_good:
        return TwoViewRefusal("ambiguous", f"{summary}; the second must stay at or below {ambiguity:.0%} of the best", **figures)
    if n_good < needed:
        return TwoViewRefusal("too_few_triangulated", f"{summary}; {needed} needed", **figures)
    return None


def _homography_motions(H_cur_ref: np.ndarray, K: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The 8 motion hypotheses (R_cur_ref, unit t_cur_ref) of a homography by Faugeras' method
    (ORB-SLAM's ReconstructH: both signs of d', all four sign pairs of the plane normal), or none
    when singular values repeat and the decomposition is undefined."""
    A = np.linalg.inv(K) @ H_cur_ref @ K
    U, d, Vt = np.linalg.svd(A)
    s = np.linalg.det(U) * np.linalg.det(Vt)
    d1, d2, d3 = d
    if d1 / d2 < _DISTINCT_SINGULAR_RATIO or d2 / d3 < _DISTINCT_SINGULAR_RATIO:
        return []
    aux1 = math.sqrt((d1 * d1 - d2 * d2) / (d1 * d1 - d3 * d3))
    aux3 = math.sqrt((d2 * d2 - d3 * d3) / (d1 * d1 - d3 * d3))
    x1 = (aux1, aux1, -aux1, -aux1)
    x3 = (aux3, -aux3, aux3, -aux3)
    root = math.sqrt((d1 * d1 - d2 * d2) * (d2 * d2 - d3 * d3))
    motions = []
    # d' = d2
    c = (d2 * d2 + d1 * d3) / ((d1 + d3) * d2)
    for i, sin in enumerate((1.0, -1.0, -1.0, 1.0)):
        s_theta = sin * root / ((d1 + d3) * d2)
        Rp = np.array([[c, 0.0, -s_theta], [0.0, 1.0, 0.0], [s_theta, 0.0, c]])
        t = U @ (np.array([x1[i], 0.0, -x3[i]]) * (d1 - d3))
        motions.append((s * U @ Rp @ Vt, t / np.linalg.norm(t)))
    # d' = -d2
    c = (d1 * d3 - d2 * d2) / ((d1 - d3) * d2)
    for i, sin in enumerate((1.0, -1.0, -1.0, 1.0)):
        s_phi = sin * root / ((d1 - d3) * d2)
        Rp = np.array([[c, 0.0, s_phi], [0.0, -1.0, 0.0], [s_phi, 0.0, -c]])
        t = U @ (np.array([x1[i], 0.0, x3[i]]) * (d1 + d3))
        motions.append((s * U @ Rp @ Vt, t / np.linalg.norm(t)))
    return motions


def _essential_motions(E: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The 4 motion hypotheses (R_cur_ref, unit t_cur_ref) of an essential matrix, in ORB-SLAM's
    order: (R1, t), (R2, t), (R1, -t), (R2, -t)."""
    U, _, Vt = np.linalg.svd(E)
    t = U[:, 2] / np.linalg.norm(U[:, 2])
    W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    R1 = U @ W @ Vt
    R2 = U @ W.T @ Vt
    R1 = -R1 if np.linalg.det(R1) < 0 else R1
    R2 = -R2 if np.linalg.det(R2) < 0 else R2
    return [(R1, t), (R2, t), (R1, -t), (R2, -t)]


def _check_motions(
    motions: list[tuple[np.ndarray, np.ndarray]], x_ref: np.ndarray, x_cur: np.ndarray, K: np.ndarray, th2: np.ndarray, parallax_rank: int
) -> list[_Candidate]:
    """Triangulate the inliers under every motion at once and judge each point (ORB-SLAM's CheckRT).

    A point is good when it is finite, in front of both cameras (unless far, see
    ``_FAR_COS_PARALLAX``) and reprojects in both images within ``th2`` (N,) px^2.
    """
    R = np.stack([m[0] for m in motions])
    t = np.stack([m[1] for m in motions])
    p_ref = _triangulate(R, t, x_ref, x_cur, K)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        p_cur = np.einsum("sij,snj->sni", R, p_ref) + t[:, None, :]
        centre_cur = -np.einsum("sji,sj->si", R, t)
        ray_cur = p_ref - centre_cur[:, None, :]
        cos_parallax = np.einsum("sni,sni->sn", p_ref, ray_cur) / (np.linalg.norm(p_ref, axis=2) * np.linalg.norm(ray_cur, axis=2))
        far = ~(cos_parallax < _FAR_COS_PARALLAX)
        in_front = far | ((p_ref[..., 2] > 0.0) & (p_cur[..., 2] > 0.0))
        err_ref = _reprojection_sq(p_ref, K, x_ref)
        err_cur = _reprojection_sq(p_cur, K, x_cur)
    good = np.isfinite(p_ref).all(axis=2) & in_front & (err_ref <= th2) & (err_cur <= th2)
    candidates = []
    for i in range(len(motions)):
        cos_good = np.sort(cos_parallax[i][good[i]])
        parallax = math.degrees(math.acos(min(1.0, cos_good[min(parallax_rank, len(cos_good) - 1)]))) if len(cos_good) else 0.0
        candidates.append(_Candidate(R[i], t[i], good[i], good[i] & ~far[i], p_ref[i], parallax))
    return candidates


def _triangulate(R: np.ndarray, t: np.ndarray, x_ref: np.ndarray, x_cur: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Linear triangulation (S, N, 3) in the reference frame of N matches (pixels) under S motions
    ``R`` (S, 3, 3), ``t`` (S, 3) from the reference to the current camera.

    The DLT equations in normalised image coordinates, solved with the point's homogeneous
    coordinate fixed to 1 through the 3x3 normal equations by the adjugate: a point at infinity,
    whose equations are singular, comes out non-finite and is rejected, and no batch raises.
    """
    K_inv = np.linalg.inv(K)
    n_ref = x_ref @ K_inv[:2, :2].T + K_inv[:2, 2]
    n_cur = x_cur @ K_inv[:2, :2].T + K_inv[:2, 2]
    P_cur = np.concatenate([R, t[:, :, None]], axis=2)  # (S, 3, 4)
    s, n = len(R), len(x_ref)
    A = np.empty((s, n, 4, 4))
    A[:, :, 0] = np.array([-1.0, 0.0, 0.0, 0.0]) + n_ref[:, 0, None] * np.array([0.0, 0.0, 1.0, 0.0])
    A[:, :, 1] = np.array([0.0, -1.0, 0.0, 0.0]) + n_ref[:, 1, None] * np.array([0.0, 0.0, 1.0, 0.0])
    A[:, :, 2] = n_cur[None, :, 0, None] * P_cur[:, None, 2] - P_cur[:, None, 0]
    A[:, :, 3] = n_cur[None, :, 1, None] * P_cur[:, None, 2] - P_cur[:, None, 1]
    M = np.swapaxes(A[..., :3], 2, 3) @ A[..., :3]  # (S, N, 3, 3)
    b = -np.einsum("snki,snk->sni", A[..., :3], A[..., 3])
    adj = adjugate(M)
    det = np.einsum("snj,snj->sn", M[..., 0, :], adj[..., :, 0])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return np.einsum("snij,snj->sni", adj, b) / det[..., None]


def _reprojection_sq(p_cam: np.ndarray, K: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Squared pixel distances (S, N) between points (S, N, 3) in a camera projected by K and x (N, 2)."""
    u = K[0, 0] * p_cam[..., 0] / p_cam[..., 2] + K[0, 2]
    v = K[1, 1] * p_cam[..., 1] / p_cam[..., 2] + K[1, 2]
    return (u - x[:, 0]) ** 2 + (v - x[:, 1]) ** 2


def _degenerate_reason(H_cur_ref: np.ndarray, K: np.ndarray) -> tuple[RefusalReason, str]:
    """Why a homography has no Faugeras decomposition: all singular values equal is a rotation
    (no translation to see), two equal is a translation along the plane normal."""
    d = np.linalg.svd(np.linalg.inv(K) @ H_cur_ref @ K, compute_uv=False)
    d = d / d[1]
    values = ", ".join(f"{v:.6f}" for v in d)
    if d[0] / d[2] < _DISTINCT_SINGULAR_RATIO**2:
        return "low_parallax", f"homography is a pure rotation (singular values {values})"
    return "degenerate", f"homography has repeated singular values ({values}): motion along the plane normal"


def _checked_inputs(
    x_ref: np.ndarray, x_cur: np.ndarray, K: np.ndarray, level_sigma2: np.ndarray | None, config: TwoViewConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Inputs as float64 arrays of checked shapes; per-match variances (M,) px^2."""
    x_ref = np.ascontiguousarray(x_ref, dtype=np.float64)
    x_cur = np.ascontiguousarray(x_cur, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    if x_ref.ndim != 2 or x_ref.shape[1] != 2 or x_ref.shape != x_cur.shape:
        raise ValueError(f"x_ref {x_ref.shape} and x_cur {x_cur.shape} must both be (M, 2) pixel arrays")
    if K.shape != (3, 3):
        raise ValueError(f"K must be 3x3, got shape {K.shape}")
    if not (np.isfinite(x_ref).all() and np.isfinite(x_cur).all()):
        raise ValueError("x_ref and x_cur must be finite pixel coordinates")
    if level_sigma2 is None:
        sigma2 = np.full(len(x_ref), config.sigma_px**2)
    else:
        sigma2 = np.asarray(level_sigma2, dtype=np.float64).reshape(-1)
        if sigma2.shape != (len(x_ref),) or not (sigma2 > 0.0).all():
            raise ValueError(f"level_sigma2 must be {len(x_ref)} positive variances in px^2, got shape {sigma2.shape}")
    return x_ref, x_cur, K, sigma2
