"""Image reading: grey conversion, size checks and errors naming the file for missing or corrupt images."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from zenslam.errors import DatasetError, ImageReadError
from zenslam.service.sources.images import image_size, read_depth_u16, read_grey, write_png


def _texture(shape, seed=0, dtype=np.uint8):
    rng = np.random.default_rng(seed)
    return rng.integers(0, np.iinfo(dtype).max, size=shape, dtype=dtype)


def test_grey_png_round_trips_exactly(tmp_path: Path):
    image = _texture((30, 40))
    write_png(tmp_path / "sub" / "a.png", image)
    back = read_grey(tmp_path / "sub" / "a.png", expected_shape=(30, 40))
    assert back.dtype == np.uint8
    np.testing.assert_array_equal(back, image)
    assert image_size(tmp_path / "sub" / "a.png") == (30, 40)


def test_colour_png_is_converted_to_grey_within_one_level_of_cvtcolor(tmp_path: Path):
    bgr = _texture((20, 24, 3), seed=1)
    write_png(tmp_path / "c.png", bgr)
    back = read_grey(tmp_path / "c.png")
    assert back.shape == (20, 24) and back.dtype == np.uint8
    # The PNG decoder converts with its own fixed-point luma weights: at most one grey level apart.
    reference = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(int)
    assert np.abs(back.astype(int) - reference).max() <= 1


def test_sixteen_bit_grey_png_is_read_as_eight_bit_grey(tmp_path: Path):
    # Only 8-bit grey PNGs are decoded as stored; any other PNG goes through OpenCV's grey conversion.
    wide = _texture((10, 12), seed=3, dtype=np.uint16)
    write_png(tmp_path / "g16.png", wide)
    back = read_grey(tmp_path / "g16.png")
    assert back.dtype == np.uint8 and back.shape == (10, 12)
    np.testing.assert_array_equal(back, cv2.imread(str(tmp_path / "g16.png"), cv2.IMREAD_GRAYSCALE))


def test_depth_png_keeps_16_bits(tmp_path: Path):
    depth = _texture((10, 12), seed=2, dtype=np.uint16)
    write_png(tmp_path / "d.png", depth)
    np.testing.assert_array_equal(read_depth_u16(tmp_path / "d.png", (10, 12)), depth)


def test_missing_image_names_the_path(tmp_path: Path):
    path = tmp_path / "nope.png"
    with pytest.raises(ImageReadError, match=r"nope\.png does not exist"):
        read_grey(path)


@pytest.mark.parametrize("content", [b"", b"\x89PNG garbage bytes that are not an image" * 3])
def test_corrupt_image_names_the_path(tmp_path: Path, content: bytes):
    path = tmp_path / "bad.png"
    path.write_bytes(content)
    with pytest.raises(ImageReadError, match=r"bad\.png could not be decoded.*corrupt"):
        read_grey(path)


def test_truncated_png_is_an_error(tmp_path: Path):
    path = tmp_path / "cut.png"
    write_png(path, _texture((64, 64)))
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(ImageReadError, match=r"cut\.png"):
        read_grey(path)


def test_wrong_size_names_both_sizes(tmp_path: Path):
    write_png(tmp_path / "small.png", _texture((30, 40)))
    with pytest.raises(ImageReadError, match=r"small\.png is 40x30 pixels but the calibration expects 50x20"):
        read_grey(tmp_path / "small.png", expected_shape=(20, 50))


def test_eight_bit_depth_is_rejected(tmp_path: Path):
    write_png(tmp_path / "d8.png", _texture((10, 12)))
    with pytest.raises(ImageReadError, match=r"d8\.png is uint8.*16-bit"):
        read_depth_u16(tmp_path / "d8.png")


def test_float_images_cannot_be_written_as_png(tmp_path: Path):
    with pytest.raises(DatasetError, match=r"f\.png.*float32"):
        write_png(tmp_path / "f.png", np.zeros((4, 4), np.float32))
