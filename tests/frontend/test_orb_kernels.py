"""The compiled quadtree and intensity-centroid kernels give exactly what the numpy formulation they replace gave."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from zenslam.frontend import orb_extractor
from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
from zenslam.frontend.orb_orientation import disc_half_widths, intensity_centroid_angles
from zenslam.frontend.orb_quadtree import distribute_quadtree

from orb_numpy_reference import reference_angles, reference_quadtree  # noqa: E402  (tests/frontend is on the path under pytest)
from test_orb_extractor import textured_image  # noqa: E402

_HALF_PATCH = 15


def random_keypoints(rng: np.random.Generator, width: int, height: int, n: int, dtype) -> tuple[np.ndarray, np.ndarray]:
    """Distinct pixels (as FAST gives them) in [0, width) x [0, height), some clustered, with FAST-like scores."""
    n = min(n, width * height)
    flat = rng.choice(width * height, n, replace=False)
    if rng.random() < 0.5:  # clusters: most keypoints within a few cells
        centres = rng.choice(width * height, 4)
        near = rng.integers(-40, 41, (n, 2)) + np.stack([centres % width, centres // width], 1)[rng.integers(0, 4, n)]
        near = np.clip(near, 0, [width - 1, height - 1])
        flat = np.unique(near[:, 1] * width + near[:, 0])
    xy = np.stack([flat % width, flat // width], 1).astype(dtype)
    response = rng.integers(7, 120, len(xy)).astype(np.float32)  # integer scores: many ties
    return xy, response


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_quadtree_equals_the_numpy_formulation_on_random_keypoints(dtype) -> None:
    rng = np.random.default_rng(41)
    for _ in range(300):
        width, height = int(rng.integers(8, 1300)), int(rng.integers(8, 400))
        xy, response = random_keypoints(rng, width, height, int(rng.integers(0, 6000)), dtype)
        n_target = int(rng.integers(0, 400))
        kept = distribute_quadtree(xy, response, width, height, n_target)
        expected = reference_quadtree(xy, response, width, height, n_target)
        assert kept.dtype == np.int64
        np.testing.assert_array_equal(kept, expected, err_msg=f"{width}x{height}, {len(xy)} keys, target {n_target}")


def test_quadtree_of_sub_pixel_coordinates_equals_the_numpy_formulation() -> None:
    rng = np.random.default_rng(7)
    for _ in range(100):
        xy = rng.uniform(0, [600, 200], (int(rng.integers(1, 3000)), 2))
        response = rng.uniform(0, 50, len(xy))
        n_target = int(rng.integers(1, 300))
        np.testing.assert_array_equal(
            distribute_quadtree(xy, response, 600, 200, n_target), reference_quadtree(xy, response, 600, 200, n_target)
        )


def test_angles_equal_the_numpy_formulation_on_random_images() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        height, width = int(rng.integers(31, 200)), int(rng.integers(31, 300))
        image = rng.integers(0, 256, (height, width), dtype=np.uint8)
        n = int(rng.integers(1, 500))
        xy = np.stack([rng.integers(15, width - 15, n), rng.integers(15, height - 15, n)], 1).astype(np.float64)
        np.testing.assert_array_equal(
            intensity_centroid_angles(image, xy, disc_half_widths()).view(np.uint32), reference_angles(image, xy).view(np.uint32)
        )
    saturated = np.full((40, 40), 255, np.uint8)  # the largest moments, and exact zeros (angle 0)
    saturated[:, 20:] = 0
    xy = np.array([[15.0, 15.0], [20.0, 20.0], [24.0, 24.0]])
    np.testing.assert_array_equal(intensity_centroid_angles(saturated, xy, disc_half_widths()), reference_angles(saturated, xy))


def test_angles_refuse_keypoints_near_the_border() -> None:
    image = np.zeros((50, 50), np.uint8)
    with pytest.raises(IndexError):
        intensity_centroid_angles(image, np.array([[14.0, 25.0]]), disc_half_widths())


def _extract_with_reference(image: np.ndarray) -> tuple:
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(orb_extractor, "distribute_quadtree", reference_quadtree)
        patch.setattr(orb_extractor, "intensity_centroid_angles", lambda image, xy, u_max: reference_angles(image, xy))
        return OrbExtractor(OrbConfig(threads=1)).extract(image)[0]


def _assert_same_features(a, b) -> None:
    for name in ("px", "level", "angle_deg", "response", "descriptors"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name


def test_extract_equals_the_numpy_formulation_on_textured_images() -> None:
    for seed in range(3):
        image = textured_image(seed)
        _assert_same_features(OrbExtractor(OrbConfig(threads=1)).extract(image)[0], _extract_with_reference(image))


@pytest.mark.dataset
def test_extract_equals_the_numpy_formulation_on_kitti(kitti_root: Path) -> None:
    import cv2

    folder = kitti_root / "sequences" / "06"
    for index in (0, 25, 50):
        for camera in ("image_0", "image_1"):
            image = cv2.imread(str(folder / camera / f"{index:06d}.png"), cv2.IMREAD_GRAYSCALE)
            _assert_same_features(OrbExtractor(OrbConfig(threads=1)).extract(image)[0], _extract_with_reference(image))


def test_reference_centroid_radius_matches_the_disc() -> None:
    u_max = disc_half_widths()
    assert u_max[0] == _HALF_PATCH and u_max[_HALF_PATCH] == 3
    assert all(u_max[v] >= math.floor(math.sqrt(_HALF_PATCH**2 - v * v)) - 1 for v in range(_HALF_PATCH + 1))
