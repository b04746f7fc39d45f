"""Two-view initialisation on synthetic matches with known truth: the fundamental matrix wins on a
general scene and the homography on a planar one, both recover the motion and the points up to
scale through outliers; rotation only, no motion and too few matches are refused with a reason.

Noise is given per keypoint and axis. ORB-SLAM's sigma of 1 px is the noise of a whole match (a
transfer error carries both keypoints'), so 1/sqrt(2) px per keypoint is "1 px" in its terms. The
planar scenes use less: when the keypoint noise reaches sigma, F's 1-dof errors outscore H's 2-dof
ones and R_H of a plane sits at the 0.45 threshold (ORB-SLAM's rule, tested as it is).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from zenslam.errors import ConfigError
from zenslam.frontend.two_view_initializer import TwoViewConfig, TwoViewRefusal, TwoViewResult, initialize_two_view
from zenslam.geometry import so3_exp, so3_log

FX, CX, CY, WIDTH, HEIGHT = 450.0, 320.0, 240.0, 640, 480
K = np.array([[FX, 0.0, CX], [0.0, FX, CY], [0.0, 0.0, 1.0]])
MATCH_1PX = 1.0 / math.sqrt(2.0)  # keypoint noise per axis that makes 1 px of match noise (px)
SIDEWAYS = (0.3, 0.02, 0.05)  # t_cur_ref (m)
SMALL_TURN = (0.01, -0.04, 0.02)  # rotation vector of R_cur_ref (rad), about 2.6 deg


@dataclasses.dataclass(frozen=True)
class Views:
    x_ref: np.ndarray  # (M, 2) px
    x_cur: np.ndarray  # (M, 2) px
    R: np.ndarray  # true R_cur_ref
    t: np.ndarray  # true t_cur_ref (m)
    p_ref: np.ndarray  # (M, 3) true points in the reference camera (m)
    outlier: np.ndarray  # (M,) bool: x_cur replaced by a random pixel


def _project(p: np.ndarray) -> np.ndarray:
    return p[:, :2] / p[:, 2:] * FX + np.array([CX, CY])


def _in_image(x: np.ndarray) -> np.ndarray:
    return (x[:, 0] >= 0) & (x[:, 0] < WIDTH) & (x[:, 1] >= 0) & (x[:, 1] < HEIGHT)


def _views(
    seed: int,
    planar: bool = False,
    noise_px: float = MATCH_1PX,
    outliers: float = 0.1,
    t: tuple[float, float, float] = SIDEWAYS,
    w: tuple[float, float, float] = SMALL_TURN,
    m: int = 1000,
) -> Views:
    """M matches of points seen by both cameras: a box 3-8 m ahead, or a floor plane 1.5 m below
    the reference camera seen up to 30 m away."""
    rng = np.random.default_rng(seed)
    R, t_ = so3_exp(np.array(w)), np.array(t, dtype=float)
    points = np.empty((0, 3))
    while len(points) < m:
        if planar:
            px = rng.uniform([0, 0], [WIDTH, HEIGHT], (m, 2))
            rays = np.column_stack([(px - [CX, CY]) / FX, np.ones(m)])
            normal = np.array([0.0, 1.0, 0.3]) / np.linalg.norm([0.0, 1.0, 0.3])
            depth = 1.5 / (rays @ normal)
            p = rays * depth[:, None]
            ok = (depth > 0) & (p[:, 2] < 30.0)
        else:
            p = np.column_stack([rng.uniform(-3.0, 3.0, (m, 2)), rng.uniform(3.0, 8.0, m)])
            ok = _in_image(_project(p))
        p_cur = p @ R.T + t_
        ok &= (p_cur[:, 2] > 0) & _in_image(_project(np.where(p_cur[:, 2:] > 0, p_cur, 1.0)))
        points = np.vstack([points, p[ok]])
    p = points[:m]
    x_ref = _project(p) + rng.normal(0.0, noise_px, (m, 2))
    x_cur = _project(p @ R.T + t_) + rng.normal(0.0, noise_px, (m, 2))
    outlier = rng.random(m) < outliers
    x_cur[outlier] = rng.uniform([0, 0], [WIDTH, HEIGHT], (int(outlier.sum()), 2))
    return Views(x_ref, x_cur, R, t_, p, outlier)


def _rotation_error_deg(result: TwoViewResult, views: Views) -> float:
    return math.degrees(np.linalg.norm(so3_log(result.T_cur_ref[:3, :3] @ views.R.T)))


def _direction_error_deg(result: TwoViewResult, views: Views) -> float:
    t = result.T_cur_ref[:3, 3]
    return math.degrees(math.acos(np.clip(t @ views.t / np.linalg.norm(views.t), -1.0, 1.0)))


def _check_reconstruction(result: TwoViewResult, views: Views, max_direction_deg: float) -> None:
    """Motion within tolerance, most inliers triangulated, outliers not, points on the truth up to scale."""
    assert _rotation_error_deg(result, views) < 0.5
    assert _direction_error_deg(result, views) < max_direction_deg
    assert np.linalg.norm(result.T_cur_ref[:3, 3]) == pytest.approx(1.0, abs=1e-12)
    tri = result.triangulated
    assert result.p_ref.shape == (int(tri.sum()), 3)
    assert not (tri & ~result.inliers).any()
    assert tri.sum() >= 0.9 * result.inliers.sum()
    assert tri[~views.outlier].mean() >= 0.85
    assert tri[views.outlier].sum() <= 0.03 * views.outlier.sum()
    # The map's scale is free: the translation has unit norm, so the points come in baselines.
    truth = views.p_ref[tri]
    scale = np.median(np.linalg.norm(truth, axis=1) / np.linalg.norm(result.p_ref, axis=1))
    assert scale == pytest.approx(np.linalg.norm(views.t), rel=0.1)
    error = np.linalg.norm(scale * result.p_ref - truth, axis=1) / np.linalg.norm(truth, axis=1)
    assert np.median(error) < 0.06
    assert np.percentile(error, 90) < 0.2


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize(("outliers", "max_direction_deg"), [(0.1, 2.0), (0.3, 3.0)])
def test_general_scene_initialises_from_the_fundamental_matrix(seed: int, outliers: float, max_direction_deg: float) -> None:
    views = _views(seed, outliers=outliers)
    result = initialize_two_view(views.x_ref, views.x_cur, K)
    assert isinstance(result, TwoViewResult), result
    assert result.model == "fundamental"
    assert result.score_ratio < 0.45
    assert result.parallax_deg >= 1.0
    _check_reconstruction(result, views, max_direction_deg)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize(("noise_px", "outliers"), [(0.5, 0.1), (0.35, 0.3)])
def test_planar_scene_initialises_from_the_homography(seed: int, noise_px: float, outliers: float) -> None:
    views = _views(seed, planar=True, noise_px=noise_px, outliers=outliers)
    result = initialize_two_view(views.x_ref, views.x_cur, K)
    assert isinstance(result, TwoViewResult), result
    assert result.model == "homography"
    assert result.score_ratio > 0.45
    _check_reconstruction(result, views, max_direction_deg=2.0)
    # Points on the floor plane: n . p = d with the true normal, up to the map's scale.
    normal = np.array([0.0, 1.0, 0.3]) / np.linalg.norm([0.0, 1.0, 0.3])
    heights = result.p_ref @ normal
    assert np.std(heights) < 0.08 * np.median(heights)


@pytest.mark.parametrize("planar", [False, True])
@pytest.mark.parametrize("seed", [0, 1])
def test_pure_rotation_is_refused_for_lack_of_parallax(planar: bool, seed: int) -> None:
    views = _views(seed, planar=planar, t=(0.0, 0.0, 0.0), w=(0.02, -0.08, 0.03))
    result = initialize_two_view(views.x_ref, views.x_cur, K)
    assert isinstance(result, TwoViewRefusal), result
    assert result.reason in ("low_parallax", "ambiguous")
    assert result.message


@pytest.mark.parametrize("noise_px", [0.0, MATCH_1PX])
def test_no_motion_is_refused(noise_px: float) -> None:
    views = _views(3, noise_px=noise_px, t=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0))
    result = initialize_two_view(views.x_ref, views.x_cur, K)
    assert isinstance(result, TwoViewRefusal), result
    assert result.reason in ("low_parallax", "ambiguous")


def test_too_little_translation_is_refused_then_enough_initialises() -> None:
    """The tracker's case: the same scene refused at a 1 cm baseline, accepted at 30 cm."""
    small = _views(4, t=(0.01, 0.0, 0.0))
    refusal = initialize_two_view(small.x_ref, small.x_cur, K)
    assert isinstance(refusal, TwoViewRefusal) and refusal.reason in ("low_parallax", "ambiguous"), refusal
    large = _views(4)
    assert isinstance(initialize_two_view(large.x_ref, large.x_cur, K), TwoViewResult)


def test_too_few_matches_are_refused() -> None:
    views = _views(5, m=99)
    result = initialize_two_view(views.x_ref, views.x_cur, K)
    assert isinstance(result, TwoViewRefusal)
    assert result.reason == "too_few_matches"
    assert "99" in result.message


def test_random_matches_are_refused() -> None:
    views = _views(6, outliers=1.0)
    result = initialize_two_view(views.x_ref, views.x_cur, K)
    assert isinstance(result, TwoViewRefusal), result


def test_same_inputs_give_the_same_bits() -> None:
    views = _views(7)
    first = initialize_two_view(views.x_ref, views.x_cur, K)
    second = initialize_two_view(views.x_ref.copy(), views.x_cur.copy(), K.copy())
    assert isinstance(first, TwoViewResult) and isinstance(second, TwoViewResult)
    assert first.T_cur_ref.tobytes() == second.T_cur_ref.tobytes()
    assert first.p_ref.tobytes() == second.p_ref.tobytes()
    assert np.array_equal(first.triangulated, second.triangulated)
    assert (first.score_ratio, first.parallax_deg) == (second.score_ratio, second.parallax_deg)


def test_uniform_level_variances_equal_sigma() -> None:
    views = _views(8)
    plain = initialize_two_view(views.x_ref, views.x_cur, K)
    levels = initialize_two_view(views.x_ref, views.x_cur, K, level_sigma2=np.ones(len(views.x_ref)))
    assert isinstance(plain, TwoViewResult) and isinstance(levels, TwoViewResult)
    assert plain.T_cur_ref.tobytes() == levels.T_cur_ref.tobytes()
    with pytest.raises(ValueError, match="level_sigma2"):
        initialize_two_view(views.x_ref, views.x_cur, K, level_sigma2=np.ones(3))


def test_mismatched_inputs_raise() -> None:
    views = _views(9)
    with pytest.raises(ValueError, match="x_ref"):
        initialize_two_view(views.x_ref[:-1], views.x_cur, K)
    with pytest.raises(ValueError, match="K"):
        initialize_two_view(views.x_ref, views.x_cur, K[:2])


@pytest.mark.parametrize(
    "field_value",
    [("ransac_iterations", 0), ("sigma_px", 0.0), ("min_matches", 7), ("homography_ratio_threshold", 1.5), ("min_parallax_deg", -1.0)],
)
def test_invalid_configuration_names_the_field(field_value: tuple[str, float]) -> None:
    field, value = field_value
    with pytest.raises(ConfigError, match=field):
        TwoViewConfig(**{field: value})
