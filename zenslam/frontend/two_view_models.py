"""Homography and fundamental matrix between two views by RANSAC, as ORB-SLAM's ``Initializer``.

Both models are fitted on the same sets of 8 correspondences, so their scores compare hypotheses
drawn from identical data. Each hypothesis is a normalised linear fit (DLT for H, the 8-point
algorithm with rank-2 enforcement for F) and is scored over every match with ORB-SLAM's
chi-square rule: a match adds ``threshold - chi2`` for each image in which its error is below the
threshold, and is an inlier when it is below in both. The hypothesis with the highest score wins;
there is no early stop, so the result depends only on the matches and the seed.

All hypotheses of one model are fitted and scored together as numpy stacks, (iterations, M).
``refine_homography``/``refine_fundamental`` go beyond ORB-SLAM: the winner is refitted by least
squares on its inliers, a minimal set's fit being too coarse to decompose into a usable motion.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

SAMPLE_SIZE = 8  # correspondences per hypothesis: the 8-point algorithm's minimal set (H needs 4, ORB-SLAM uses 8)

CHI2_2DOF = 5.991  # 95% quantile of chi-square with 2 dof: a point-to-point transfer error
CHI2_1DOF = 3.841  # 95% quantile of chi-square with 1 dof: a point-to-line distance


@dataclass(frozen=True)
class ModelFit:
    """The best hypothesis of one model and the matches that agree with it."""

    matrix: np.ndarray  # (3, 3) H_cur_ref (x_cur ~ H x_ref) or F_cur_ref (x_cur^T F x_ref = 0), pixels
    inliers: np.ndarray  # (M,) bool
    score: float  # ORB-SLAM's score: sum over images and matches of (threshold - chi2) where below threshold


def draw_sample_sets(n_matches: int, iterations: int, rng: np.random.Generator) -> np.ndarray:
    """(iterations, 8) indices into the matches, 8 distinct ones per row (Floyd's algorithm, vectorised)."""
    if n_matches < SAMPLE_SIZE:
        raise ValueError(f"{n_matches} matches cannot give sets of {SAMPLE_SIZE} distinct ones")
    sets = np.empty((iterations, SAMPLE_SIZE), dtype=np.int64)
    for k, j in enumerate(range(n_matches - SAMPLE_SIZE, n_matches)):
        t = rng.integers(0, j + 1, size=iterations)
        taken = (sets[:, :k] == t[:, None]).any(axis=1)
        sets[:, k] = np.where(taken, j, t)
    return sets


def normalize_points(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre points (M, 2) and scale each axis to unit mean absolute deviation (ORB-SLAM's
    ``Normalize``); returns the normalised points and the 3x3 ``T`` with ``x_n = T x``."""
    mean = x.mean(axis=0)
    centred = x - mean
    dev = np.abs(centred).mean(axis=0)
    scale = 1.0 / np.where(dev > 0.0, dev, 1.0)
    T = np.array([[scale[0], 0.0, -mean[0] * scale[0]], [0.0, scale[1], -mean[1] * scale[1]], [0.0, 0.0, 1.0]])
    return centred * scale, T


def fit_homographies(xn_ref: np.ndarray, xn_cur: np.ndarray) -> np.ndarray:
    """DLT homographies (S, 3, 3) with x_cur ~ H x_ref from stacks of normalised points (S, n, 2)."""
    u1, v1 = xn_ref[..., 0], xn_ref[..., 1]
    u2, v2 = xn_cur[..., 0], xn_cur[..., 1]
    zero, one = np.zeros_like(u1), np.ones_like(u1)
    rows_v = np.stack([zero, zero, zero, -u1, -v1, -one, v2 * u1, v2 * v1, v2], axis=-1)
    rows_u = np.stack([u1, v1, one, zero, zero, zero, -u2 * u1, -u2 * v1, -u2], axis=-1)
    A = np.concatenate([rows_v, rows_u], axis=-2)
    return _null_vectors(A).reshape(-1, 3, 3)


def fit_fundamentals(xn_ref: np.ndarray, xn_cur: np.ndarray) -> np.ndarray:
    """8-point fundamental matrices (S, 3, 3) with x_cur^T F x_ref = 0, forced to rank 2, from
    stacks of normalised points (S, n, 2)."""
    u1, v1 = xn_ref[..., 0], xn_ref[..., 1]
    u2, v2 = xn_cur[..., 0], xn_cur[..., 1]
    A = np.stack([u2 * u1, u2 * v1, u2, v2 * u1, v2 * v1, v2, u1, v1, np.ones_like(u1)], axis=-1)
    F = _null_vectors(A).reshape(-1, 3, 3)
    U, w, Vt = np.linalg.svd(F)
    w[:, 2] = 0.0
    return U @ (w[:, :, None] * Vt)


def score_homographies(
    H_cur_ref: np.ndarray, x_ref: np.ndarray, x_cur: np.ndarray, inv_sigma2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Scores (S,) and inliers (S, M) of homographies (S, 3, 3) by the symmetric transfer error.

    The inverse is the adjugate: a homography is defined up to scale, and the adjugate exists for
    a singular hypothesis too (its transfers are then non-finite, hence outliers).
    """
    H_ref_cur = adjugate(H_cur_ref)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        chi2_cur = _transfer_sq(H_cur_ref, x_ref, x_cur) * inv_sigma2
        chi2_ref = _transfer_sq(H_ref_cur, x_cur, x_ref) * inv_sigma2
    return _score(chi2_ref, chi2_cur, CHI2_2DOF, CHI2_2DOF)


def score_fundamentals(
    F_cur_ref: np.ndarray, x_ref: np.ndarray, x_cur: np.ndarray, inv_sigma2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Scores (S,) and inliers (S, M) of fundamental matrices (S, 3, 3) by the distance of each
    point to its epipolar line in both images: inlier below the 1-dof threshold, scored against
    the 2-dof one so that F and H scores are on one scale (ORB-SLAM's ``CheckFundamental``)."""
    xh_ref = np.vstack([x_ref.T, np.ones(len(x_ref))])  # (3, M)
    xh_cur = np.vstack([x_cur.T, np.ones(len(x_cur))])
    lines_cur = F_cur_ref @ xh_ref  # (S, 3, M)
    lines_ref = np.swapaxes(F_cur_ref, 1, 2) @ xh_cur
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        chi2_cur = _line_distance_sq(lines_cur, xh_cur) * inv_sigma2
        chi2_ref = _line_distance_sq(lines_ref, xh_ref) * inv_sigma2
    return _score(chi2_ref, chi2_cur, CHI2_1DOF, CHI2_2DOF)


def find_homography(x_ref: np.ndarray, x_cur: np.ndarray, sets: np.ndarray, inv_sigma2: np.ndarray) -> ModelFit | None:
    """The best-scoring homography over the sample ``sets`` (S, 8); None when none scores above 0."""
    xn_ref, T_ref = normalize_points(x_ref)
    xn_cur, T_cur = normalize_points(x_cur)
    Hn = fit_homographies(xn_ref[sets], xn_cur[sets])
    H = adjugate(T_cur) @ Hn @ T_ref  # the adjugate of T_cur is its inverse up to scale
    scores, inliers = score_homographies(H, x_ref, x_cur, inv_sigma2)
    return _best(H, scores, inliers)


def find_fundamental(x_ref: np.ndarray, x_cur: np.ndarray, sets: np.ndarray, inv_sigma2: np.ndarray) -> ModelFit | None:
    """The best-scoring fundamental matrix over the sample ``sets`` (S, 8); None when none scores above 0."""
    xn_ref, T_ref = normalize_points(x_ref)
    xn_cur, T_cur = normalize_points(x_cur)
    Fn = fit_fundamentals(xn_ref[sets], xn_cur[sets])
    F = T_cur.T @ Fn @ T_ref
    scores, inliers = score_fundamentals(F, x_ref, x_cur, inv_sigma2)
    return _best(F, scores, inliers)


def refine_homography(x_ref: np.ndarray, x_cur: np.ndarray, fit: ModelFit, inv_sigma2: np.ndarray, rounds: int) -> ModelFit:
    """Refit a homography on its inliers by least squares while the score rises, at most ``rounds`` times."""
    return _refine(x_ref, x_cur, fit, inv_sigma2, rounds, fit_homographies, score_homographies, lambda Tc, M, Tr: adjugate(Tc) @ M @ Tr)


def refine_fundamental(x_ref: np.ndarray, x_cur: np.ndarray, fit: ModelFit, inv_sigma2: np.ndarray, rounds: int) -> ModelFit:
    """Refit a fundamental matrix on its inliers by least squares while the score rises, at most ``rounds`` times."""
    return _refine(x_ref, x_cur, fit, inv_sigma2, rounds, fit_fundamentals, score_fundamentals, lambda Tc, M, Tr: Tc.T @ M @ Tr)


def _refine(
    x_ref: np.ndarray,
    x_cur: np.ndarray,
    fit: ModelFit,
    inv_sigma2: np.ndarray,
    rounds: int,
    fitter: Callable[[np.ndarray, np.ndarray], np.ndarray],
    scorer: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    denormalize: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
) -> ModelFit:
    """Least-squares refits on the inliers, each normalised afresh, kept while the score rises."""
    for _ in range(rounds):
        rows = np.flatnonzero(fit.inliers)
        if len(rows) < SAMPLE_SIZE:
            break
        xn_ref, T_ref = normalize_points(x_ref[rows])
        xn_cur, T_cur = normalize_points(x_cur[rows])
        M = denormalize(T_cur, fitter(xn_ref[None], xn_cur[None])[0], T_ref)
        scores, inliers = scorer(M[None], x_ref, x_cur, inv_sigma2)
        if not scores[0] > fit.score:
            break
        fit = ModelFit(M, inliers[0], float(scores[0]))
    return fit


def _best(models: np.ndarray, scores: np.ndarray, inliers: np.ndarray) -> ModelFit | None:
    """The first hypothesis of highest score, as ORB-SLAM keeps the first strictly better one."""
    best = int(np.argmax(scores))
    if not scores[best] > 0.0:
        return None
    return ModelFit(models[best].copy(), inliers[best].copy(), float(scores[best]))


def _score(chi2_ref: np.ndarray, chi2_cur: np.ndarray, threshold: float, score_threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM's score of chi-square stacks (S, M) per image; a non-finite error is an outlier."""
    in_ref = chi2_ref <= threshold
    in_cur = chi2_cur <= threshold
    score = np.where(in_ref, score_threshold - chi2_ref, 0.0).sum(axis=1)
    score += np.where(in_cur, score_threshold - chi2_cur, 0.0).sum(axis=1)
    return score, in_ref & in_cur


def _transfer_sq(H_b_a: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> np.ndarray:
    """Squared distances (S, M) px^2 between points x_b and x_a mapped by homographies (S, 3, 3)."""
    p = H_b_a[:, :, :2] @ x_a.T + H_b_a[:, :, 2:]  # (S, 3, M)
    du = p[:, 0] / p[:, 2] - x_b[:, 0]
    dv = p[:, 1] / p[:, 2] - x_b[:, 1]
    return du * du + dv * dv


def _line_distance_sq(lines: np.ndarray, xh: np.ndarray) -> np.ndarray:
    """Squared distances (S, M) px^2 of homogeneous points (3, M) to lines (S, 3, M)."""
    num = (lines * xh).sum(axis=1)
    return num * num / (lines[:, 0] ** 2 + lines[:, 1] ** 2)


def _null_vectors(A: np.ndarray) -> np.ndarray:
    """Right singular vectors (S, 9) of the smallest singular value of stacked systems (S, n, 9)."""
    return np.linalg.svd(A, full_matrices=A.shape[-2] < A.shape[-1])[2][:, -1, :]


def adjugate(M: np.ndarray) -> np.ndarray:
    """Adjugate of 3x3 matrices (..., 3, 3): ``det(M) * inv(M)``, defined for singular ones too."""
    r0, r1, r2 = M[..., 0, :], M[..., 1, :], M[..., 2, :]
    return np.stack([np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)], axis=-1)
