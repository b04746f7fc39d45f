"""ORB extraction: counts per level, spread, determinism, rotation and scale behaviour."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from zenslam.errors import ConfigError, ImageReadError
from zenslam.frontend.orb_extractor import (
    Features,
    OrbConfig,
    OrbExtractor,
    base_to_level_px,
    features_per_level,
    level_to_base_px,
)
from zenslam.frontend.orb_quadtree import distribute_quadtree


def textured_image(seed: int = 0, height: int = 480, width: int = 640) -> np.ndarray:
    """Blurred noise under random axis-aligned rectangles: corners at every scale."""
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, (height // 8, width // 8)).astype(np.uint8)
    image = cv2.resize(cv2.GaussianBlur(coarse, (0, 0), 1.0), (width, height), interpolation=cv2.INTER_CUBIC)
    for _ in range(700):
        x, y = rng.integers(0, width), rng.integers(0, height)
        dx, dy = rng.integers(4, 50, 2)
        cv2.rectangle(image, (int(x), int(y)), (int(x + dx), int(y + dy)), int(rng.integers(0, 256)), -1)
    return image


@pytest.fixture(scope="module")
def image() -> np.ndarray:
    return textured_image()


@pytest.fixture(scope="module")
def extracted(image: np.ndarray) -> tuple[Features, list[np.ndarray]]:
    return OrbExtractor().extract(image)


def test_features_per_level_is_orbslam_geometric_series() -> None:
    counts = features_per_level(1200, 1.2, 8)
    assert counts.sum() == 1200
    assert counts.tolist() == [261, 217, 181, 151, 126, 105, 87, 72]
    ratios = counts[1:-1] / counts[:-2]
    np.testing.assert_allclose(ratios, 1 / 1.2, atol=0.01)


def test_extract_count_levels_types_and_pyramid(image: np.ndarray, extracted) -> None:
    features, pyramid = extracted
    extractor = OrbExtractor()
    n = len(features)
    assert abs(n - 1200) <= 120
    per_level = np.bincount(features.level, minlength=8)
    np.testing.assert_allclose(per_level, extractor.n_per_level, rtol=0.1, atol=3)
    assert features.px.dtype == np.float32 and features.px.shape == (n, 2)
    assert features.level.dtype == np.int16
    assert features.angle_deg.dtype == np.float32 and features.response.dtype == np.float32
    assert features.descriptors.dtype == np.uint8 and features.descriptors.shape == (n, 32)
    assert np.all((features.angle_deg >= 0) & (features.angle_deg < 360))
    assert np.all(features.response >= 7)
    np.testing.assert_allclose(features.scale_factors, 1.2 ** np.arange(8))
    np.testing.assert_allclose(features.inv_level_sigma2, 1.2 ** (-2.0 * np.arange(8)))
    np.testing.assert_allclose(features.size_px, 31 * 1.2 ** features.level.astype(float), rtol=1e-6)
    # ORB-SLAM keeps keypoints 19 level pixels inside each level image
    for level, level_image in enumerate(pyramid):
        on_level = base_to_level_px(features.px[features.level == level], level_image.shape, pyramid[0].shape)
        np.testing.assert_allclose(on_level, np.rint(on_level), atol=1e-3)  # FAST fires on level pixels
        h, w = level_image.shape
        assert on_level[:, 0].min() >= 19 - 1e-3 and on_level[:, 0].max() <= w - 20 + 1e-3
        assert on_level[:, 1].min() >= 19 - 1e-3 and on_level[:, 1].max() <= h - 20 + 1e-3
        assert abs(h - round(480 / 1.2**level)) <= 1 and abs(w - round(640 / 1.2**level)) <= 1


def test_features_are_spread_over_the_image(extracted) -> None:
    features, _ = extracted
    cells = np.zeros((4, 4), int)
    np.add.at(cells, ((features.px[:, 1] * 4 / 480).astype(int), (features.px[:, 0] * 4 / 640).astype(int)), 1)
    assert (cells > 0).sum() >= 14
    assert cells.max() <= 3 * cells.mean()  # no cell holds a disproportionate share


def test_extract_is_deterministic_and_threads_do_not_change_it(image: np.ndarray, extracted) -> None:
    features, _ = extracted
    again, _ = OrbExtractor().extract(image)
    for name in ("px", "level", "angle_deg", "response", "descriptors"):
        np.testing.assert_array_equal(getattr(features, name), getattr(again, name))
    other = textured_image(seed=1)
    (threaded_left, _), (threaded_right, _) = OrbExtractor(OrbConfig(threads=2)).extract_pair(image, other)
    (serial_left, _), (serial_right, _) = OrbExtractor(OrbConfig(threads=1)).extract_pair(image, other)
    np.testing.assert_array_equal(threaded_left.descriptors, serial_left.descriptors)
    np.testing.assert_array_equal(threaded_right.px, serial_right.px)


def test_fast_min_threshold_with_score_filter_equals_fast_ini(image: np.ndarray) -> None:
    # _detect_cells relies on this: FAST(20) == FAST(7) keeping scores >= 20 (both with NMS)
    low = cv2.FastFeatureDetector_create(7, True).detect(image)
    high = cv2.FastFeatureDetector_create(20, True).detect(image)
    filtered = {k.pt for k in low if k.response >= 20}
    assert filtered == {k.pt for k in high}


def test_low_contrast_cells_fall_back_to_the_min_threshold() -> None:
    rng = np.random.default_rng(3)
    image = np.full((240, 320), 128, np.uint8)
    for y in range(4, 232, 16):  # faint, separate squares: contrast 10-14 grey levels, below FAST's 20
        for x in range(4, 312, 16):
            shade = 128 + int(rng.choice([-1, 1]) * rng.integers(10, 15))
            cv2.rectangle(image, (x, y), (x + 8, y + 8), shade, -1)
    features, _ = OrbExtractor(OrbConfig(n_features=300)).extract(image)
    assert len(features) > 100
    assert features.response.max() < 20  # every keypoint came from the min-threshold fallback


def test_quadtree_keeps_the_best_keypoint_per_cluster() -> None:
    rng = np.random.default_rng(0)
    centres = np.array([[20.0, 20.0], [180.0, 20.0], [20.0, 80.0], [180.0, 80.0]])
    xy = np.concatenate([c + rng.uniform(-5, 5, (25, 2)) for c in centres])
    response = rng.uniform(0, 50, len(xy))
    keep = distribute_quadtree(xy, response, 200, 100, 4)
    assert len(keep) == 4
    for cluster in range(4):
        members = np.arange(cluster * 25, (cluster + 1) * 25)
        assert members[np.argmax(response[members])] in keep
    # fewer keypoints than wanted: all are kept; many wanted: at least that many nodes
    np.testing.assert_array_equal(distribute_quadtree(xy[:10], response[:10], 200, 100, 50), np.arange(10))
    dense = rng.uniform(0, [200, 100], (2000, 2))
    kept = distribute_quadtree(dense, rng.uniform(0, 1, 2000), 200, 100, 300)
    assert 300 <= len(kept) <= 330


def test_descriptors_are_rotation_invariant(image: np.ndarray, extracted) -> None:
    features, _ = extracted
    h, w = image.shape
    rotation = cv2.getRotationMatrix2D((w / 2, h / 2), 30.0, 1.0)
    rotated, _ = OrbExtractor().extract(cv2.warpAffine(image, rotation, (w, h), flags=cv2.INTER_LINEAR))
    projected = features.px @ rotation[:, :2].T + rotation[:, 2]
    # keypoints detected again at the same place and level: the descriptor test proper
    distance = np.linalg.norm(projected[:, None, :] - rotated.px[None, :, :], axis=2)
    repeated = ((distance < 2.0) & (features.level[:, None] == rotated.level[None, :])).any(axis=1)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(features.descriptors, rotated.descriptors)
    query = np.array([m.queryIdx for m in matches])
    train = np.array([m.trainIdx for m in matches])
    correct = np.linalg.norm(projected[query] - rotated.px[train], axis=1) < 2.0
    assert repeated.sum() > 250
    assert np.isin(query[correct], np.flatnonzero(repeated)).sum() > 0.8 * repeated.sum()
    inside = np.all((projected > 20) & (projected < [w - 20, h - 20]), axis=1)
    assert correct.sum() > 0.3 * inside.sum()
    # the intensity-centroid angle turns with the image: cv2's +30 deg is -30 deg in (u right, v down)
    turn = (rotated.angle_deg[train[correct]] - features.angle_deg[query[correct]] + 180) % 360 - 180
    assert abs(np.median(turn) + 30.0) < 1.0
    assert np.mean(np.abs(turn + 30.0) < 5.0) > 0.8


def test_a_smaller_image_moves_matches_down_one_level(image: np.ndarray, extracted) -> None:
    features, _ = extracted
    h, w = image.shape
    resized = cv2.resize(image, (round(w / 1.2), round(h / 1.2)), interpolation=cv2.INTER_LINEAR)
    small, _ = OrbExtractor().extract(resized)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(features.descriptors, small.descriptors)
    query = np.array([m.queryIdx for m in matches])
    train = np.array([m.trainIdx for m in matches])
    correct = np.linalg.norm(features.px[query] / 1.2 - small.px[train], axis=1) < 2.0
    upper = correct & (features.level[query] >= 1)
    assert upper.sum() > 400
    shift = features.level[query[upper]].astype(int) - small.level[train[upper]]
    assert np.mean(shift == 1) > 0.95


def test_bad_images_and_configs_are_rejected() -> None:
    extractor = OrbExtractor()
    with pytest.raises(ImageReadError, match="grey uint8"):
        extractor.extract(np.zeros((100, 100, 3), np.uint8))
    with pytest.raises(ImageReadError, match="grey uint8"):
        extractor.extract(np.zeros((100, 100), np.float32))
    with pytest.raises(ImageReadError, match="too small"):
        extractor.extract(np.zeros((30, 100), np.uint8))
    with pytest.raises(ConfigError, match="scale_factor"):
        OrbConfig(scale_factor=1.0)
    with pytest.raises(ConfigError, match="FAST thresholds"):
        OrbConfig(ini_fast_threshold=5, min_fast_threshold=7)


def test_blank_image_gives_no_features() -> None:
    features, pyramid = OrbExtractor().extract(np.full((120, 160), 90, np.uint8))
    assert len(features) == 0 and features.descriptors.shape == (0, 32)
    assert len(pyramid) == 8


def test_kitti_frame_extraction(kitti_root: Path) -> None:
    image = cv2.imread(str(kitti_root / "sequences" / "06" / "image_0" / "000000.png"), cv2.IMREAD_GRAYSCALE)
    features, _ = OrbExtractor().extract(image)
    assert abs(len(features) - 1200) <= 120
    assert np.all(np.bincount(features.level, minlength=8) > 0)


def test_level_pixels_map_to_the_level0_pixel_they_image() -> None:
    """A Gaussian blob at a known level-0 position is found, on every pyramid level, at the level pixel
    that ``level_to_base_px`` maps back to that position (within 0.05 px); x * scale misses by up to
    (scale - 1) / 2 px, the KITTI-sized image's level sizes are rounded so each axis has its own ratio."""
    height, width = 376, 1241
    centre = np.array([617.3, 190.6])  # level-0 px
    v, u = np.mgrid[0:height, 0:width]
    blob = 40.0 + 200.0 * np.exp(-((u - centre[0]) ** 2 + (v - centre[1]) ** 2) / (2 * 9.0**2))
    pyramid = OrbExtractor(OrbConfig(n_levels=8)).build_pyramid(np.rint(blob).astype(np.uint8))
    worst_scaled = 0.0
    for level, img in enumerate(pyramid[1:], start=1):
        w = img.astype(np.float64) - 40.0
        vv, uu = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
        found = np.array([(w * uu).sum() / w.sum(), (w * vv).sum() / w.sum()])  # centroid, level px
        mapped = level_to_base_px(found[None], img.shape, pyramid[0].shape)[0]
        assert np.abs(mapped - centre).max() < 0.05, (level, mapped, centre)
        back = base_to_level_px(mapped[None], img.shape, pyramid[0].shape)[0]
        np.testing.assert_allclose(back, found, atol=1e-9)
        worst_scaled = max(worst_scaled, np.abs(found * 1.2**level - centre).max())
    assert worst_scaled > 1.0  # the old convention's error at level 7 (scale 3.58) is over a pixel


def test_the_warm_up_compiles_the_extractor_kernels_for_the_types_extraction_uses() -> None:
    # A frame decoded from the bus is read-only, one from an in-process source is not: neither may
    # leave a kernel to compile (seconds, on a machine's first start) at a run's first frame.
    from zenslam.frontend import orb_descriptor, orb_fast, orb_orientation, orb_quadtree
    from zenslam.frontend.kernel_warm_up import warm_up_kernels

    warm_up_kernels()
    kernels = (orb_orientation._centroid_moments, orb_descriptor._separable_blur, orb_descriptor._descriptors,
               orb_quadtree._morton_codes, orb_quadtree._distribute,
               orb_fast._fast_in_cells)  # fmt: skip
    compiled = [len(k.signatures) for k in kernels]
    assert all(compiled)
    read_only = textured_image(0, 370, 1226)
    read_only[:, 400:800] = 90  # flat: empty cells, FAST(min) on their mosaic
    read_only.setflags(write=False)
    for image in (textured_image(0, 370, 1226), read_only):
        OrbExtractor(OrbConfig(threads=1)).extract(image)
        assert [len(k.signatures) for k in kernels] == compiled  # nothing left to compile at the first frame
