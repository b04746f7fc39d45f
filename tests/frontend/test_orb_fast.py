"""The compiled FAST kernel gives OpenCV's corners and scores, and the extractor ORB-SLAM's per-cell FAST as OpenCV's per-window calls give it."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from zenslam.frontend import orb_extractor
from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
from zenslam.frontend.orb_fast import fast_in_windows, strength_map

from orb_fast_reference import opencv_fast, window_detect_cells  # noqa: E402  (tests/frontend is on the path under pytest)
from test_orb_extractor import textured_image  # noqa: E402


def _corners(xy: np.ndarray, score: np.ndarray) -> list[tuple[int, int, int]]:
    return sorted(zip(np.asarray(xy[:, 1], np.int64).tolist(), np.asarray(xy[:, 0], np.int64).tolist(), np.asarray(score, np.int64).tolist()))


def _assert_fast_equals_opencv(image: np.ndarray, threshold: int) -> int:
    """The kernel on the whole image against OpenCV's FastFeatureDetector; returns the corner count."""
    expected = _corners(*opencv_fast(image, threshold))
    found = _corners(*fast_in_windows(image, np.array([[0, 0, image.shape[1], image.shape[0]]]), threshold))
    assert found == expected, (image.shape, threshold)
    return len(found)


def _level_images(paths: list[Path]) -> list[np.ndarray]:
    extractor = OrbExtractor()
    return [level for path in paths for level in extractor.build_pyramid(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))]


def test_corners_and_scores_equal_opencv_on_random_and_small_images() -> None:
    rng = np.random.default_rng(11)
    n_corners = 0
    for trial in range(60):
        height, width = (int(v) for v in rng.integers(1, 90, 2))
        image = rng.integers(0, 256, (height, width), dtype=np.uint8)
        if trial % 3 == 1:
            image = cv2.GaussianBlur(image, (0, 0), 1.2)
        elif trial % 3 == 2:  # few grey levels: plateaus of equal scores, NMS ties
            image = (image // 64 * 64).astype(np.uint8)
        for threshold in (0, 1, 7, 20, 60, 254):
            n_corners += _assert_fast_equals_opencv(image, threshold)
    assert n_corners > 10_000


def test_corners_and_scores_equal_opencv_on_synthetic_images() -> None:
    for seed in range(3):
        for threshold in (7, 20):
            assert _assert_fast_equals_opencv(textured_image(seed), threshold) > 500
    saturated = np.zeros((64, 64), np.uint8)  # 0 and 255 squares: the differences at their extremes
    saturated[16:40, 20:44] = 255
    saturated[30:34, 30:34] = 0
    for threshold in (0, 7, 20, 254, 255, 300):  # OpenCV clamps the threshold to [0, 255]
        _assert_fast_equals_opencv(saturated, threshold)


def test_windows_equal_one_opencv_call_per_window() -> None:
    image = textured_image(4)
    rng = np.random.default_rng(2)
    x0 = rng.integers(0, 600, 40)
    y0 = rng.integers(0, 440, 40)
    windows = np.stack([x0, y0, np.minimum(x0 + rng.integers(1, 50, 40), 640), np.minimum(y0 + rng.integers(1, 50, 40), 480)], axis=1)
    windows[:2] = [[0, 0, 640, 480], [100, 100, 107, 107]]  # the whole image; the smallest window with a candidate
    xy, score = fast_in_windows(image, windows, 7)
    expected_xy, expected_score = [], []
    for x_start, y_start, x_stop, y_stop in windows.tolist():
        window_xy, window_score = opencv_fast(image[y_start:y_stop, x_start:x_stop], 7)
        expected_xy.append(window_xy.astype(np.int64) + [x_start, y_start])
        expected_score.append(window_score.astype(np.int64))
    # window after window, each in OpenCV's raster order, overlapping windows each with their own
    np.testing.assert_array_equal(xy, np.concatenate(expected_xy))
    np.testing.assert_array_equal(score, np.concatenate(expected_score))


def test_strengths_do_not_depend_on_the_box_for_pixels_3_px_inside_it() -> None:
    image = textured_image(6)
    whole = strength_map(image, (0, 0, 640, 480))
    crop = strength_map(image, (100, 50, 300, 170))
    np.testing.assert_array_equal(crop[3:-3, 3:-3], whole[53:167, 103:297])
    assert not crop[:3].any() and not crop[-3:].any() and not crop[:, :3].any() and not crop[:, -3:].any()
    assert np.count_nonzero(crop) > 1000


def test_windows_outside_the_image_are_refused() -> None:
    with pytest.raises(ValueError, match="inside the image"):
        fast_in_windows(np.zeros((20, 20), np.uint8), np.array([[0, 0, 21, 20]]), 7)


def test_fast_ini_equals_fast_min_keeping_the_scores_from_ini() -> None:
    # _detect_cells relies on this: a corner's score does not depend on the threshold it was found
    # at, and the weaker corners FAST(min) adds score below ini, so they suppress none of FAST(ini)'s.
    for image in (textured_image(1), textured_image(2)):
        low = _corners(*fast_in_windows(image, np.array([[0, 0, 640, 480]]), 7))
        high = _corners(*fast_in_windows(image, np.array([[0, 0, 640, 480]]), 20))
        assert [c for c in low if c[2] >= 20] == high
        assert len(high) > 500


@pytest.mark.dataset
def test_corners_and_scores_equal_opencv_on_kitti_and_euroc_levels(kitti_root: Path, euroc_micro: Path) -> None:
    kitti = kitti_root / "sequences" / "06"
    paths = [kitti / "image_0" / "000000.png", kitti / "image_1" / "000040.png"]
    paths += sorted((euroc_micro / "mav0" / "cam0" / "data").glob("*.png"))[:2]
    for level in _level_images(paths):
        for threshold in (7, 20):
            _assert_fast_equals_opencv(level, threshold)


def _extract_with(image: np.ndarray, detect_cells) -> orb_extractor.Features:
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(orb_extractor, "_detect_cells", detect_cells)
        return OrbExtractor(OrbConfig(threads=1)).extract(image)[0]


def _assert_same_features(a, b) -> None:
    for name in ("px", "level", "angle_deg", "response", "descriptors"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name


def test_detect_cells_equals_opencv_per_window_on_textured_and_faint_images() -> None:
    config = OrbConfig()
    faint = (textured_image(5) // 16 + 100).astype(np.uint8)  # contrast below FAST(ini): most cells fall back
    for image in (textured_image(3), faint):
        for level in OrbExtractor().build_pyramid(image):
            xy, score, width, height = orb_extractor._detect_cells(level, config)
            expected_xy, expected_score, expected_width, expected_height = window_detect_cells(level, config)
            np.testing.assert_array_equal(xy, expected_xy)
            np.testing.assert_array_equal(score, expected_score)
            assert (width, height) == (expected_width, expected_height)
    _assert_same_features(OrbExtractor(OrbConfig(threads=1)).extract(faint)[0], _extract_with(faint, window_detect_cells))


@pytest.mark.dataset
def test_extract_equals_opencv_per_window_on_kitti_and_euroc(kitti_root: Path, euroc_micro: Path) -> None:
    kitti = kitti_root / "sequences" / "06"
    paths = [kitti / camera / f"{index:06d}.png" for index in (0, 50) for camera in ("image_0", "image_1")]
    paths += sorted((euroc_micro / "mav0" / "cam0" / "data").glob("*.png"))[::5][:3]
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        _assert_same_features(OrbExtractor(OrbConfig(threads=1)).extract(image)[0], _extract_with(image, window_detect_cells))


def test_the_warm_up_compiles_the_extractor_kernels_for_the_types_extraction_uses() -> None:
    # A frame decoded from the bus is read-only, one from an in-process source is not: neither may
    # leave a kernel to compile (seconds, on a machine's first start) at a run's first frame.
    from zenslam.frontend import orb_descriptor, orb_fast, orb_orientation, orb_quadtree
    from zenslam.frontend.kernel_warm_up import warm_up_kernels

    warm_up_kernels()
    kernels = (orb_fast._strengths, orb_fast._suppressed, orb_orientation._centroid_moments, orb_descriptor._separable_blur,
               orb_descriptor._descriptors, orb_quadtree._morton_codes, orb_quadtree._distribute)  # fmt: skip
    compiled = [len(k.signatures) for k in kernels]
    assert all(compiled)
    read_only = textured_image(0, 370, 1226)
    read_only.setflags(write=False)
    for image in (textured_image(0, 370, 1226), read_only):
        OrbExtractor(OrbConfig(threads=1)).extract(image)
        assert [len(k.signatures) for k in kernels] == compiled  # nothing left to compile at the first frame
