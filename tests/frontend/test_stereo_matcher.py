"""Stereo matching on synthetic rectified pairs with known disparity, and on KITTI."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, ConfigError
from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
from zenslam.frontend.stereo_matcher import StereoMatchConfig, match_stereo

DISPARITY_TOP_PX = 12.4  # rows above the middle
DISPARITY_BOTTOM_PX = 31.7  # rows below
CALIBRATION = PinholeCalibration(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480, baseline_m=0.1)


def textured_image(seed: int, height: int = 480, width: int = 640) -> np.ndarray:
    """Random rectangles over blurred noise, softened like a real lens (Gaussian sigma 1.5 px)."""
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, (height // 8, width // 8)).astype(np.uint8)
    image = cv2.resize(cv2.GaussianBlur(coarse, (0, 0), 1.0), (width, height), interpolation=cv2.INTER_CUBIC)
    for _ in range(700):
        x, y = rng.integers(0, width), rng.integers(0, height)
        dx, dy = rng.integers(4, 50, 2)
        cv2.rectangle(image, (int(x), int(y)), (int(x + dx), int(y + dy)), int(rng.integers(0, 256)), -1)
    return cv2.GaussianBlur(image, (0, 0), 1.5)


def stereo_pair(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left, right and the true disparity per row: right(u, v) = left(u + d(v), v), plus sensor noise.

    Both images are resampled from one source at offsets with mirrored fractional parts, so the
    interpolation blurs them equally.
    """
    source = textured_image(seed)
    h, w = source.shape
    disparity = np.where(np.arange(h) < h // 2, DISPARITY_TOP_PX, DISPARITY_BOTTOM_PX)
    offset = (1.0 - disparity % 1.0) / 2.0
    u = np.arange(w, dtype=np.float64)[None, :]
    map_y = np.repeat(np.arange(h, dtype=np.float32)[:, None], w, axis=1)
    left = cv2.remap(source, (u + offset[:, None]).astype(np.float32), map_y, cv2.INTER_LINEAR)
    right = cv2.remap(source, (u + offset[:, None] + disparity[:, None]).astype(np.float32), map_y, cv2.INTER_LINEAR)
    rng = np.random.default_rng(seed + 100)

    def noisy(image: np.ndarray) -> np.ndarray:
        return np.clip(image + rng.normal(0.0, 1.5, image.shape), 0, 255).astype(np.uint8)

    return noisy(left), noisy(right), disparity


@pytest.fixture(scope="module")
def extracted():
    left, right, disparity = stereo_pair()
    (features, pyramid), (features_right, pyramid_right) = OrbExtractor().extract_pair(left, right)
    return features, pyramid, features_right, pyramid_right, disparity


@pytest.fixture(scope="module")
def matched(extracted):
    features, pyramid, features_right, pyramid_right, disparity = extracted
    matches = match_stereo(features, features_right, pyramid, pyramid_right, CALIBRATION)
    return features, features_right, matches, disparity


def test_disparities_match_the_truth(matched) -> None:
    features, _, matches, disparity = matched
    true_d = disparity[np.rint(features.px[:, 1]).astype(int)]
    ok = matches.depth_m > 0
    error = np.abs(features.px[ok, 0] - matches.right_u[ok] - true_d[ok])
    assert np.median(error) < 0.3
    assert np.percentile(error, 95) < 1.0
    measured = features.px[ok, 0] - matches.right_u[ok]
    np.testing.assert_allclose(matches.depth_m[ok], CALIBRATION.bf / measured, rtol=1e-4)
    assert np.all(matches.right_u[~ok] == -1) and np.all(matches.depth_m[~ok] == -1)
    assert np.all(matches.right_index[~ok] == -1) and np.all(matches.right_index[ok] >= 0)


def test_most_matchable_keypoints_are_matched(matched) -> None:
    features, features_right, matches, disparity = matched
    true_d = disparity[np.rint(features.px[:, 1]).astype(int)]
    target = np.stack([features.px[:, 0] - true_d, features.px[:, 1]], axis=1)
    # matchable: the right image has a keypoint at the true place, at a level the matcher searches
    near = np.abs(target[:, None, :] - features_right.px[None, :, :]).max(axis=2) < 1.5
    adjacent = np.abs(features.level[:, None].astype(int) - features_right.level[None, :]) <= 1
    matchable = (near & adjacent).any(axis=1)
    in_view = target[:, 0] > 25
    ok = matches.depth_m > 0
    assert matchable.sum() > 0.6 * in_view.sum()
    assert (ok & matchable).sum() > 0.85 * matchable.sum()
    assert ok.sum() > 0.55 * in_view.sum()  # detection repeatability, not matching, bounds this


def test_min_depth_limits_the_disparity_search(extracted) -> None:
    f_left, p_left, f_right, p_right, _ = extracted
    # max disparity bf / 2.5 m = 20 px: the bottom half (31.7 px) has no match, the top half keeps its
    near_limited = match_stereo(f_left, f_right, p_left, p_right, CALIBRATION, StereoMatchConfig(min_depth_m=2.5))
    ok = near_limited.depth_m > 0
    assert ok.sum() > 150
    disparity = f_left.px[ok, 0] - near_limited.right_u[ok]
    assert disparity.max() < 20.0
    assert np.mean(np.abs(disparity - DISPARITY_TOP_PX) < 1.0) > 0.95


def test_a_disparity_offset_is_added_to_every_disparity(extracted, matched) -> None:
    """``disparity_offset_px`` (Middlebury's doffs) shifts each matched right u by -offset, so the
    disparity grows by it and the depth is bf over the corrected disparity; the matches are the same."""
    f_left, p_left, f_right, p_right, _ = extracted
    _, _, plain, _ = matched
    shifted = match_stereo(f_left, f_right, p_left, p_right, CALIBRATION, StereoMatchConfig(disparity_offset_px=0.25))
    ok = plain.depth_m > 0
    np.testing.assert_array_equal(shifted.depth_m > 0, ok)
    np.testing.assert_allclose(shifted.right_u[ok], plain.right_u[ok] - 0.25, atol=1e-4)
    disparity = f_left.px[ok, 0] - shifted.right_u[ok]
    np.testing.assert_allclose(shifted.depth_m[ok], CALIBRATION.bf / disparity, rtol=1e-4)


def test_no_right_keypoints_gives_no_matches(matched) -> None:
    features, features_right, _, _ = matched
    pyramid = [np.zeros((480, 640), np.uint8)] * 8
    empty = features_right.subset(np.zeros(0, np.int64))
    matches = match_stereo(features, empty, pyramid, pyramid, CALIBRATION)
    assert matches.n_matches == 0 and np.all(matches.right_u == -1)


def test_mono_calibration_and_bad_config_are_rejected(matched) -> None:
    features, features_right, _, _ = matched
    mono = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480)
    with pytest.raises(CalibrationError, match="baseline"):
        match_stereo(features, features_right, [], [], mono)
    with pytest.raises(ConfigError, match="max_descriptor_distance"):
        StereoMatchConfig(max_descriptor_distance=0)
    with pytest.raises(ConfigError, match="disparity_offset_px"):
        StereoMatchConfig(disparity_offset_px=float("nan"))


def _kitti_pair(kitti_root: Path, index: int) -> tuple[np.ndarray, np.ndarray]:
    sequence = kitti_root / "sequences" / "06"
    left = cv2.imread(str(sequence / "image_0" / f"{index:06d}.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(sequence / "image_1" / f"{index:06d}.png"), cv2.IMREAD_GRAYSCALE)
    return left, right


KITTI_CALIBRATION = PinholeCalibration(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370, baseline_m=0.5372)


@pytest.mark.dataset
def test_kitti_frame_0_has_many_stereo_points(kitti_root: Path) -> None:
    left, right = _kitti_pair(kitti_root, 0)
    # ORB-SLAM2's KITTI setting is 2000 features; the 1200 default gives ~470 matches here
    for n_features, expected in ((2000, 500), (1200, 400)):
        (f_left, p_left), (f_right, p_right) = OrbExtractor(OrbConfig(n_features=n_features)).extract_pair(left, right)
        matches = match_stereo(f_left, f_right, p_left, p_right, KITTI_CALIBRATION)
        depth = matches.depth_m
        assert ((depth >= 0.5) & (depth <= 200.0)).sum() >= expected, n_features
