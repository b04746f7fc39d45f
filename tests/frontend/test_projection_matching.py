"""The compiled search by projection equals its numpy formulation exactly, on random scenes of
every kind the tracker searches (motion model, local map, relocalisation) and on their edge cases."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.frontend.feature_matcher import search_by_projection

from projection_numpy_reference import search_by_projection as numpy_search  # noqa: E402  (tests/frontend is on the path)


def _scene(rng: np.random.Generator, n_points: int, n_keypoints: int, width: float = 1226.0, height: float = 370.0):
    """Keypoints over an image and projections near some of them, with descriptors close to theirs."""
    kp_px = rng.uniform([0, 0], [width, height], (n_keypoints, 2))
    kp_px[: n_keypoints // 4] = np.round(kp_px[: n_keypoints // 4])  # integer positions, as level 0 keypoints
    kp_level = rng.integers(0, 8, n_keypoints)
    kp_desc = rng.integers(0, 256, (n_keypoints, 32), dtype=np.uint8)
    source = rng.integers(0, n_keypoints, n_points)
    proj_px = kp_px[source] + rng.normal(0, 3.0, (n_points, 2))
    point_desc = kp_desc[source].copy()
    flips = rng.random((n_points, 32)) < 0.15
    point_desc[flips] ^= rng.integers(1, 256, int(flips.sum()), dtype=np.uint8)
    far = rng.random(n_points) < 0.3  # points whose keypoint is elsewhere: ambiguous candidates only
    point_desc[far] = rng.integers(0, 256, (int(far.sum()), 32), dtype=np.uint8)
    predicted = np.clip(kp_level[source] + rng.integers(-1, 2, n_points), 0, 7)
    kp_right_u = np.where(rng.random(n_keypoints) < 0.6, kp_px[:, 0] - rng.uniform(1, 60, n_keypoints), -1.0)
    proj_right_u = kp_right_u[source] + rng.normal(0, 2.0, n_points)
    return proj_px, predicted, point_desc, kp_px, kp_level, kp_desc, kp_right_u, proj_right_u


CASES = {
    "motion model": dict(ratio=None, min_level_offset=-1, max_level_offset=1, max_distance=100),
    "local map": dict(ratio=0.8, min_level_offset=-1, max_level_offset=0, max_distance=100),
    "open levels": dict(ratio=0.9, min_level_offset=None, max_level_offset=None, max_distance=256),
    "tight": dict(ratio=0.6, min_level_offset=0, max_level_offset=0, max_distance=50, max_passes=1),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("seed", range(12))
def test_the_compiled_search_equals_numpys(case, seed):
    rng = np.random.default_rng(seed)
    proj_px, predicted, point_desc, kp_px, kp_level, kp_desc, kp_right_u, proj_right_u = _scene(
        rng, int(rng.integers(1, 900)), int(rng.integers(1, 2400))
    )
    scale = 1.2 ** predicted
    radius = rng.choice([1.0, 4.0, 15.0, 30.0]) * scale  # per projection, as the tracker folds in the level's scale
    proj_px[rng.random(len(proj_px)) < 0.02] = np.nan  # points behind the camera
    radius[rng.random(len(radius)) < 0.02] = 0.0
    already = rng.random(len(kp_px)) < 0.1
    stereo = seed % 2 == 0
    kwargs = dict(CASES[case], already_matched=already)
    if stereo:
        kwargs.update(kp_right_u=kp_right_u, proj_right_u=proj_right_u)
    args = (proj_px, predicted, point_desc, kp_px, kp_level, kp_desc, radius)
    expected = numpy_search(*args, **kwargs)
    got = search_by_projection(*args, **kwargs)
    assert got.dtype == expected.dtype == np.int32
    np.testing.assert_array_equal(got, expected)
    assert (expected >= 0).sum() > 0 or len(proj_px) < 5


def test_a_scalar_radius_and_crowded_windows():
    """Many projections on one cluster: keypoints are contested over several passes."""
    rng = np.random.default_rng(7)
    kp_px = rng.uniform(100, 140, (300, 2))
    kp_desc = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    proj_px = rng.uniform(95, 145, (400, 2))
    point_desc = kp_desc[rng.integers(0, 300, 400)]
    levels_kp, levels_proj = rng.integers(0, 3, 300), rng.integers(0, 3, 400)
    for ratio in (None, 0.8):
        for passes in (1, 2, 4, 8):
            args = (proj_px, levels_proj, point_desc, kp_px, levels_kp, kp_desc, 12.0)
            kwargs = dict(ratio=ratio, max_passes=passes, min_level_offset=None, max_level_offset=None)
            np.testing.assert_array_equal(search_by_projection(*args, **kwargs), numpy_search(*args, **kwargs))


def test_nothing_to_search():
    empty_px, empty_desc = np.zeros((0, 2)), np.zeros((0, 32), np.uint8)
    one_px, one_desc = np.array([[10.0, 10.0]]), np.zeros((1, 32), np.uint8)
    assert search_by_projection(empty_px, [], empty_desc, one_px, [0], one_desc, 5.0).shape == (0,)
    assert search_by_projection(one_px, [0], one_desc, empty_px, [], empty_desc, 5.0).tolist() == [-1]
    assert search_by_projection(one_px, [0], one_desc, one_px, [0], one_desc, 5.0).tolist() == [0]
    assert search_by_projection(one_px, [0], one_desc, one_px + 5.0, [0], one_desc, 5.0).tolist() == [-1]  # strict window
