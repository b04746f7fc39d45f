"""The compiled FAST kernel gives OpenCV's corners, scores and order, and the extractor the keypoints of its former OpenCV path."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from zenslam.frontend import orb_extractor
from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
from zenslam.frontend.orb_fast import fast_in_cells, fast_in_windows, strength_map

from orb_fast_reference import mosaic_detect_cells, opencv_fast  # noqa: E402  (tests/frontend is on the path under pytest)
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


def test_the_fallback_mosaic_equals_one_call_per_window_away_from_the_margins() -> None:
    # fast_in_cells tiles the empty cells' windows (cell + 3 px margin) into a mosaic; away from the
    # margins, where non-maximum suppression cannot see a neighbouring tile, it must find exactly
    # the corners (and scores) of one FAST call per window. FAST(ini) at 255 finds nothing, so all
    # 280 cells fall back: 12 mosaic rows, blank tiles after the last cell, and the last column's
    # windows past the region (replicated pixels).
    image = textured_image(4)
    region = image[16:-16, 16:-16]
    height, width = region.shape
    n_cols, n_rows = int(width / 30), int(height / 30)
    w_cell, h_cell = -(-width // n_cols), -(-height // n_rows)
    assert n_cols * w_cell > width
    xy, score = fast_in_cells(image, (16, 16, 16 + width, 16 + height), (n_cols, n_rows, w_cell, h_cell), (255, 7), 24)
    expected = set()
    for row in range(n_rows):
        for col in range(n_cols):
            y0, x0 = row * h_cell, col * w_cell
            window_xy, window_score = opencv_fast(region[y0 : y0 + h_cell + 6, x0 : x0 + w_cell + 6], 7)
            expected |= {(x0 + int(x), y0 + int(y), int(r)) for (x, y), r in zip(window_xy.tolist(), window_score.tolist())}
    assert len(expected) > 500

    def inner(x: int, y: int) -> bool:
        # >= 4 px inside its window and the region: NMS saw only its own window's pixels (the
        # mosaic's replicated rows and columns past the region hold candidates a crop has not)
        inside = x < width - 4 and y < height - 4
        return inside and 1 <= (x - 3) % w_cell < w_cell - 1 and 1 <= (y - 3) % h_cell < h_cell - 1

    found = {(int(x), int(y), int(r)) for (x, y), r in zip(xy.tolist(), score.tolist())}
    assert {k for k in found if inner(k[0], k[1])} == {k for k in expected if inner(k[0], k[1])}
    assert len(found) > len({k for k in found if inner(k[0], k[1])})  # the margins hold corners too


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


def test_detect_cells_equals_the_former_opencv_path_on_textured_and_faint_images() -> None:
    config = OrbConfig()
    faint = (textured_image(5) // 16 + 100).astype(np.uint8)  # contrast below FAST(ini): most cells fall back
    patchy = textured_image(7)
    patchy[:, 200:450] = 128  # flat columns: empty cells beside textured ones, margins against texture
    for image in (textured_image(3), faint, patchy):
        for level in OrbExtractor().build_pyramid(image):
            xy, score, width, height = orb_extractor._detect_cells(level, config)
            expected_xy, expected_score, expected_width, expected_height = mosaic_detect_cells(level, config)
            np.testing.assert_array_equal(xy, expected_xy)
            np.testing.assert_array_equal(score, expected_score)
            assert xy.dtype == expected_xy.dtype and score.dtype == expected_score.dtype
            assert (width, height) == (expected_width, expected_height)
    _assert_same_features(OrbExtractor(OrbConfig(threads=1)).extract(faint)[0], _extract_with(faint, mosaic_detect_cells))


@pytest.mark.dataset
def test_extract_equals_the_former_opencv_path_on_kitti_and_euroc(kitti_root: Path, euroc_micro: Path) -> None:
    kitti = kitti_root / "sequences" / "06"
    paths = [kitti / camera / f"{index:06d}.png" for index in (0, 50) for camera in ("image_0", "image_1")]
    paths += sorted((euroc_micro / "mav0" / "cam0" / "data").glob("*.png"))[::5][:3]
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        _assert_same_features(OrbExtractor(OrbConfig(threads=1)).extract(image)[0], _extract_with(image, mosaic_detect_cells))
