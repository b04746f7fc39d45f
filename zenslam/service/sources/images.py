"""Reading and writing dataset images with errors that name the file and the problem."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from zenslam.errors import DatasetError, ImageReadError


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _read(path: Path) -> np.ndarray:
    """The bytes of the image file at ``path``; ImageReadError when it is missing or unreadable."""
    if not path.is_file():
        raise ImageReadError(f"image {path} does not exist; check the dataset folder is complete", str(path), "missing")
    try:
        return np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise ImageReadError(f"image {path} cannot be read ({exc}); check its permissions", str(path), "unreadable") from exc


def _decode(path: Path, data: np.ndarray, flags: int) -> np.ndarray:
    """Decode the bytes ``data`` of the image file ``path`` with OpenCV ``flags``; ImageReadError when that fails."""
    image = cv2.imdecode(data, flags) if data.size else None
    if image is None:
        raise ImageReadError(
            f"image {path} could not be decoded ({data.size} bytes): the file is corrupt or not an image; "
            "re-download or replace it",
            str(path),
        )
    return image


def _is_8bit_grey_png(data: np.ndarray) -> bool:
    """Whether ``data`` is a PNG whose header (IHDR: bit depth at byte 24, colour type at 25) says 8-bit grey."""
    return data.size > 25 and data[:8].tobytes() == _PNG_SIGNATURE and data[24] == 8 and data[25] == 0


def _check_shape(path: Path, image: np.ndarray, expected_shape: tuple[int, int] | None) -> None:
    if expected_shape is not None and image.shape[:2] != tuple(expected_shape):
        h, w = image.shape[:2]
        raise ImageReadError(
            f"image {path} is {w}x{h} pixels but the calibration expects {expected_shape[1]}x{expected_shape[0]}; "
            "the image or the calibration belongs to another camera",
            str(path),
        )


def read_grey(path: Path, expected_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read an image as 8-bit grey (H, W); colour images are converted by the decoder
    (luma weights, within one grey level of ``cv2.cvtColor``).

    ``expected_shape`` is (height, width) in pixels; a different size raises ImageReadError.
    """
    path = Path(path)
    data = _read(path)
    # An 8-bit grey PNG (KITTI, EuRoC) decodes to the same pixels either way, and faster as stored
    # than through OpenCV's grey-conversion path (benchmarks/stage_processes.md).
    image = _decode(path, data, cv2.IMREAD_UNCHANGED if _is_8bit_grey_png(data) else cv2.IMREAD_GRAYSCALE)
    _check_shape(path, image, expected_shape)
    return image


def read_depth_u16(path: Path, expected_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read a single-channel 16-bit depth PNG as stored (raw units, 0 = unknown), shape (H, W)."""
    path = Path(path)
    image = _decode(path, _read(path), cv2.IMREAD_UNCHANGED)
    if image.dtype != np.uint16 or image.ndim != 2:
        channels = 1 if image.ndim == 2 else image.shape[2]
        raise ImageReadError(
            f"depth image {path} is {image.dtype} with {channels} channel(s); "
            "a depth image must be a single-channel 16-bit PNG",
            str(path),
        )
    _check_shape(path, image, expected_shape)
    return image


def image_size(path: Path) -> tuple[int, int]:
    """(height, width) in pixels of the image at ``path`` (decodes it once)."""
    path = Path(path)
    return _decode(path, _read(path), cv2.IMREAD_GRAYSCALE).shape[:2]


def write_png(path: Path, image: np.ndarray) -> None:
    """Write ``image`` (uint8 or uint16, grey or BGR) losslessly as PNG, creating parent folders."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if image.dtype not in (np.uint8, np.uint16):
        raise DatasetError(f"cannot write {path}: PNG images must be uint8 or uint16, got {image.dtype}")
    if not cv2.imwrite(str(path), image):
        raise DatasetError(f"OpenCV could not write the image {path}; check the folder is writable")
