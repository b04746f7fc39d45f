"""The compiled rBRIEF kernel gives OpenCV's ORB.compute bytes for every keypoint on ORB.compute's blurred
image, reads OpenCV's pattern back exactly, and blurs as OpenCV's baseline path does, on any CPU."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from zenslam.frontend import orb_extractor
from zenslam.frontend.orb_descriptor import BORDER_PX, blur, describe, describe_blurred, rbrief_pattern
from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor

from orb_opencv_reference import reference_baseline_blur, reference_blur, reference_describe, reference_orb  # noqa: E402  (tests/frontend is on the path under pytest)
from test_orb_extractor import textured_image  # noqa: E402

# float32 angles (degrees, as bit patterns) at which a float32 cosine and sine would round some steered
# pattern point to another pixel than the double ones rounded to float32 do: OpenCV's are the latter.
_TRIG_ROUNDING_ANGLES = np.array(
    [0x40506FD5, 0x4152F830, 0x41790BBA, 0x41CD146C, 0x41F60B7E, 0x42073719,
     0x42372AA5, 0x4262882E, 0x42941D84, 0x4309710E, 0x43456EC5, 0x4370F610],
    np.uint32,
).view(np.float32)  # fmt: skip


@pytest.fixture(scope="module")
def pattern() -> np.ndarray:
    return rbrief_pattern()


def _quadrant_angles() -> np.ndarray:
    """0, 90, 180, 270 and 360 degrees and their float32 neighbours a few ulps either side."""
    angles = []
    for centre in np.array([0.0, 90.0, 180.0, 270.0, 360.0], np.float32):
        below = above = centre
        angles.append(centre)
        for _ in range(4):
            below, above = np.nextafter(below, np.float32(-1.0)), np.nextafter(above, np.float32(400.0))
            angles += [below, above]
    angles += [np.float32(1e-30), np.float32(1e-7), np.float32(359.99997)]
    return np.array([a for a in angles if a >= 0], np.float32)


def _assert_same(image: np.ndarray, xy: np.ndarray, angle: np.ndarray, pattern: np.ndarray) -> None:
    ours, opencv = describe_blurred(reference_blur(image), xy, angle, pattern), reference_describe(image, xy, angle)
    differing = np.flatnonzero((ours != opencv).any(axis=1))
    assert len(differing) == 0, f"{len(differing)} of {len(xy)} differ, first at {xy[differing[0]]} angle {angle[differing[0]]!r}"


def test_the_pattern_read_back_is_opencvs_shape(pattern) -> None:
    assert pattern.shape == (512, 2) and pattern.dtype == np.float32
    assert pattern.min() >= -15 and pattern.max() <= 15  # inside the 31 px patch
    assert np.all(np.any(pattern[0::2] != pattern[1::2], axis=1))  # each test compares two different points
    assert np.array_equal(rbrief_pattern(), pattern)


def test_descriptors_equal_opencv_on_random_images_and_angles(pattern) -> None:
    rng = np.random.default_rng(11)
    for trial in range(30):
        height, width = int(rng.integers(2 * BORDER_PX + 1, 160)), int(rng.integers(2 * BORDER_PX + 1, 260))
        image = rng.integers(0, 256, (height, width), dtype=np.uint8)
        if trial % 2:  # smooth images: many equal grey levels after the blur, so ties in the tests
            image = cv2.resize(image[: height // 6 + 1, : width // 6 + 1], (width, height), interpolation=cv2.INTER_CUBIC)
        n = int(rng.integers(1, 400))
        xy = np.stack([rng.integers(BORDER_PX, width - BORDER_PX, n), rng.integers(BORDER_PX, height - BORDER_PX, n)], 1)
        angle = rng.uniform(0.0, 360.0, n).astype(np.float32)
        _assert_same(image, xy.astype(np.float64), angle, pattern)


def test_descriptors_equal_opencv_near_the_quadrants_and_at_the_border(pattern) -> None:
    rng = np.random.default_rng(12)
    image = cv2.GaussianBlur(rng.integers(0, 256, (120, 200), dtype=np.uint8), (0, 0), 1.0)
    rows, cols = image.shape
    lo, hi_x, hi_y = BORDER_PX, cols - BORDER_PX - 1, rows - BORDER_PX - 1  # the closest centres allowed
    corners = np.array([[lo, lo], [hi_x, lo], [lo, hi_y], [hi_x, hi_y], [lo, 60], [hi_x, 60], [100, lo], [100, hi_y]], np.float64)
    angles = np.concatenate([_quadrant_angles(), _TRIG_ROUNDING_ANGLES, rng.uniform(0, 360, 40).astype(np.float32)])
    xy = np.repeat(corners, len(angles), axis=0)
    _assert_same(image, xy, np.tile(angles, len(corners)), pattern)


def test_descriptors_equal_opencv_at_angles_where_float32_trigonometry_would_not(pattern) -> None:
    rng = np.random.default_rng(13)
    image = rng.integers(0, 256, (200, 200), dtype=np.uint8)
    for _ in range(10):
        xy = rng.integers(BORDER_PX, 200 - BORDER_PX, (len(_TRIG_ROUNDING_ANGLES), 2)).astype(np.float64)
        _assert_same(image, xy, _TRIG_ROUNDING_ANGLES, pattern)


def test_sub_pixel_keypoints_are_rounded_as_opencv_rounds_them(pattern) -> None:
    rng = np.random.default_rng(14)
    image = rng.integers(0, 256, (100, 100), dtype=np.uint8)
    base = rng.integers(BORDER_PX + 1, 100 - BORDER_PX - 1, (300, 2))
    xy = base + rng.choice([0.0, 0.25, 0.5, -0.5, 0.49999997, 0.7], (300, 2))  # halves round to even
    _assert_same(image, xy, rng.uniform(0, 360, 300).astype(np.float32), pattern)


def test_keypoints_inside_the_border_are_refused(pattern) -> None:
    image = np.zeros((60, 60), np.uint8)
    for xy in ([[BORDER_PX - 1, 30]], [[30, 60 - BORDER_PX]]):
        with pytest.raises(IndexError):
            describe(image, np.array(xy, np.float64), np.zeros(1, np.float32), pattern)
    assert describe(image, np.zeros((0, 2)), np.zeros(0, np.float32), pattern).shape == (0, 32)


def _extract_with_opencv(image: np.ndarray) -> orb_extractor.Features:
    orb = reference_orb()
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(orb_extractor, "describe", lambda level, xy, angle, pattern: reference_describe(level, xy, angle, orb))
        return OrbExtractor(OrbConfig(threads=1)).extract(image)[0]


def _assert_close_to_opencvs_extraction(image: np.ndarray) -> None:
    """The same keypoints as with ORB.compute's descriptors; the descriptors equal where this CPU's
    OpenCV blurs as its baseline path does (an AVX2 OpenCV rounds a few pixels otherwise:
    tests/runtime/test_opencv_dispatch.py compares the extraction with the baseline's exactly)."""
    ours, opencv = OrbExtractor(OrbConfig(threads=1)).extract(image)[0], _extract_with_opencv(image)
    assert len(ours) > 0
    for name in ("px", "level", "angle_deg", "response"):
        assert getattr(ours, name).tobytes() == getattr(opencv, name).tobytes(), name
    differing_bits = np.unpackbits(ours.descriptors ^ opencv.descriptors, axis=1).sum(axis=1)
    assert differing_bits.mean() < 0.05, (differing_bits.mean(), differing_bits.max())


def test_the_blur_is_opencvs_baseline_filter_on_random_images_and_pyramids() -> None:
    rng = np.random.default_rng(21)
    images = [rng.integers(0, 256, (int(rng.integers(4, 120)), int(rng.integers(4, 200))), dtype=np.uint8) for _ in range(40)]
    images += [textured_image(seed) for seed in range(2)]
    for image in images:
        for level in OrbExtractor().build_pyramid(image) if min(image.shape) >= 46 else [image]:
            assert np.array_equal(blur(level), reference_baseline_blur(level)), level.shape


def test_the_blur_is_within_a_grey_level_of_orb_computes_on_this_cpu() -> None:
    for seed in range(3):
        image = textured_image(seed)
        difference = blur(image).astype(np.int16) - reference_blur(image).astype(np.int16)
        assert np.abs(difference).max() <= 1 and np.mean(difference != 0) < 1e-3


def test_extraction_is_close_to_opencvs_descriptors_on_textured_images() -> None:
    for seed in range(3):
        _assert_close_to_opencvs_extraction(textured_image(seed))


@pytest.mark.dataset
def test_extraction_is_close_to_opencvs_descriptors_on_kitti(kitti_root: Path) -> None:
    folder = kitti_root / "sequences" / "06"
    for index in (0, 15, 30, 45):
        for camera in ("image_0", "image_1"):
            _assert_close_to_opencvs_extraction(cv2.imread(str(folder / camera / f"{index:06d}.png"), cv2.IMREAD_GRAYSCALE))


@pytest.mark.dataset
def test_extraction_is_close_to_opencvs_descriptors_on_euroc(euroc_micro: Path) -> None:
    images = sorted((euroc_micro / "mav0").glob("cam[01]/data/*.png"))
    assert images
    for path in images[:: max(1, len(images) // 6)]:
        _assert_close_to_opencvs_extraction(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))
