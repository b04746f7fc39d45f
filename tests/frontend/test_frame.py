"""Frames: area search on the keypoint grid, and the stereo, RGB-D and mono constructors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, ImageReadError, ZenslamError
from zenslam.frontend.frame import Frame, make_mono_frame, make_rgbd_frame, make_stereo_frame, rgbd_right_coordinates
from zenslam.frontend.orb_extractor import Features, OrbExtractor

CALIBRATION = PinholeCalibration(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480, baseline_m=0.1)
MONO = PinholeCalibration(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)


def random_features(n: int, seed: int = 0) -> Features:
    rng = np.random.default_rng(seed)
    scale = 1.2 ** np.arange(8)
    return Features(
        px=(rng.uniform(0, 1, (n, 2)) * [640, 480]).astype(np.float32),
        level=rng.integers(0, 8, n).astype(np.int16),
        angle_deg=rng.uniform(0, 360, n).astype(np.float32),
        response=rng.uniform(7, 60, n).astype(np.float32),
        descriptors=rng.integers(0, 256, (n, 32)).astype(np.uint8),
        scale_factors=scale,
        inv_level_sigma2=1.0 / scale**2,
    )


def textured_image(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    image = cv2.resize(rng.integers(0, 256, (60, 80)).astype(np.uint8), (640, 480), interpolation=cv2.INTER_CUBIC)
    for _ in range(700):
        x, y = rng.integers(0, 640), rng.integers(0, 480)
        dx, dy = rng.integers(4, 50, 2)
        cv2.rectangle(image, (int(x), int(y)), (int(x + dx), int(y + dy)), int(rng.integers(0, 256)), -1)
    return cv2.GaussianBlur(image, (0, 0), 1.5)


@pytest.fixture(scope="module")
def frame() -> Frame:
    features = random_features(3000)
    none = np.full(len(features), -1.0, np.float32)
    return Frame(7, 123, MONO, features, none, none.copy())


def brute_force(frame: Frame, u: float, v: float, r: float, lo: int, hi: int) -> np.ndarray:
    px, level = frame.features.px, frame.features.level
    keep = (np.abs(px[:, 0] - u) < r) & (np.abs(px[:, 1] - v) < r)
    if lo >= 0:
        keep &= level >= lo
    if hi >= 0:
        keep &= level <= hi
    return np.flatnonzero(keep)


def test_indices_in_area_equals_brute_force(frame: Frame) -> None:
    rng = np.random.default_rng(1)
    for _ in range(200):
        u, v = rng.uniform(-30, 670), rng.uniform(-30, 510)
        r = rng.uniform(1, 60)
        lo, hi = sorted(rng.integers(-1, 8, 2).tolist())
        np.testing.assert_array_equal(frame.indices_in_area(u, v, r, lo, hi), brute_force(frame, u, v, r, lo, hi))


def test_batch_area_search_equals_single_queries(frame: Frame) -> None:
    rng = np.random.default_rng(2)
    m = 300
    u, v = rng.uniform(0, 640, m), rng.uniform(0, 480, m)
    radius = rng.uniform(2, 30, m)
    lo = rng.integers(-1, 4, m)
    hi = np.where(rng.uniform(size=m) < 0.5, -1, lo + 2)
    u[5] = np.nan  # an invalid projection finds nothing
    query, keypoint = frame.indices_in_areas(u, v, radius, lo, hi)
    assert np.all(np.diff(query) >= 0)
    for i in range(m):
        expected = np.zeros(0, np.int64) if i == 5 else brute_force(frame, u[i], v[i], radius[i], lo[i], hi[i])
        np.testing.assert_array_equal(keypoint[query == i], expected)


def test_stereo_frame_has_depth_and_unprojects() -> None:
    left = textured_image()
    disparity = 20.0  # right(u) = left(u + 20): a fronto-parallel plane at bf / 20 = 2.5 m
    right = np.ascontiguousarray(np.concatenate([left[:, 20:], left[:, -20:]], axis=1))
    timings: dict[str, float] = {}
    frame = make_stereo_frame(3, 42, left, right, CALIBRATION, OrbExtractor(), timings_ms=timings)
    assert frame.index == 3 and frame.stamp_ns == 42 and frame.n_keypoints == len(frame.features)
    assert set(timings) == {"extraction", "stereo_matching"} and all(t > 0 for t in timings.values())
    ok = frame.has_depth
    assert ok.sum() > 0.5 * frame.n_keypoints
    np.testing.assert_allclose(np.median(frame.depth_m[ok]), 2.5, rtol=0.01)
    p_cam = frame.unproject()
    assert np.all(np.isnan(p_cam[~ok]))
    np.testing.assert_allclose(p_cam[ok, 2], frame.depth_m[ok], rtol=1e-6)
    reprojected = p_cam[ok, :2] / p_cam[ok, 2:] * 500.0 + [320.0, 240.0]
    np.testing.assert_allclose(reprojected, frame.features.px[ok], atol=1e-3)


def test_rgbd_right_coordinates_use_the_nearest_depth_pixel() -> None:
    depth = np.zeros((480, 640), np.float32)
    depth[:, :320] = 2.0
    depth[100, 400] = 4.0
    depth[200, 500] = np.nan
    px = np.array([[10.4, 20.6], [399.6, 100.4], [500.0, 200.0], [600.0, 300.0]], np.float32)
    right_u, depth_m = rgbd_right_coordinates(px, depth, bf=50.0)
    np.testing.assert_allclose(depth_m, [2.0, 4.0, -1.0, -1.0])
    np.testing.assert_allclose(right_u, [10.4 - 25.0, 399.6 - 12.5, -1.0, -1.0], rtol=1e-6)


def test_rgbd_frame_reads_depth_at_keypoints() -> None:
    left = textured_image()
    u = np.arange(640, dtype=np.float32)[None, :]
    depth = np.repeat(1.0 + u / 640.0, 480, axis=0)  # depth grows from 1 m to 2 m left to right
    depth[:, 600:] = 0.0
    frame = make_rgbd_frame(0, 0, left, depth, CALIBRATION, OrbExtractor())
    px = frame.features.px
    valid = np.rint(px[:, 0]) < 600
    np.testing.assert_allclose(frame.depth_m[valid], 1.0 + np.rint(px[valid, 0]) / 640.0, rtol=1e-6)
    np.testing.assert_allclose(frame.right_u[valid], px[valid, 0] - CALIBRATION.bf / frame.depth_m[valid], rtol=1e-5)
    assert np.all(frame.depth_m[~valid] == -1) and np.all(frame.right_u[~valid] == -1)


def test_mono_frame_has_no_depth() -> None:
    frame = make_mono_frame(1, 5, textured_image(), MONO, OrbExtractor())
    assert frame.n_keypoints > 1000
    assert np.all(frame.right_u == -1) and np.all(frame.depth_m == -1)
    assert len(frame.indices_in_area(320.0, 240.0, 50.0)) > 0


def test_wrong_inputs_are_rejected() -> None:
    image = textured_image()
    extractor = OrbExtractor()
    with pytest.raises(CalibrationError, match="baseline"):
        make_stereo_frame(0, 0, image, image, MONO, extractor)
    with pytest.raises(ImageReadError, match="640x480"):
        make_stereo_frame(0, 0, image[:400], image, CALIBRATION, extractor)
    with pytest.raises(ImageReadError, match="depth image"):
        make_rgbd_frame(0, 0, image, np.zeros((480, 640), np.uint16), CALIBRATION, extractor)
    with pytest.raises(CalibrationError, match="virtual baseline"):
        make_rgbd_frame(0, 0, image, np.zeros((480, 640), np.float32), MONO, extractor)


def test_frame_rejects_per_keypoint_arrays_of_the_wrong_length() -> None:
    features = random_features(10)
    with pytest.raises(ZenslamError, match="one entry per keypoint"):
        Frame(0, 0, MONO, features, np.full(9, -1.0, np.float32), np.full(10, -1.0, np.float32))
