"""Images in sensor frames: raw bytes or lossless PNG."""

from __future__ import annotations

from typing import Literal

import numpy as np

from zenslam.errors import MessageError
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.codec.packing import unpack

ImageEncodingName = Literal["raw", "png"]
IMAGE_ENCODING_CODES: dict[str, int] = {"raw": pb.IMAGE_ENCODING_RAW, "png": pb.IMAGE_ENCODING_PNG}


def png_bytes(image: np.ndarray, compression: int = 1) -> bytes:
    """A lossless PNG of a uint8 grey image at zlib level ``compression`` (0-9).

    Run-length deflate: natural images have few long repeats for LZ77 to find, so it compresses
    them about as well as the default strategy, and faster. Every row takes PNG's Sub filter (each
    pixel less its left neighbour) rather than libpng's choice per row among all five, which tries
    each: much less CPU for slightly larger images, the trade a recorder of every frame wants
    (benchmarks/footprint.md has the figures). An OpenCV without
    ``IMWRITE_PNG_FILTER`` chooses per row.
    """
    # OpenCV is imported here, by the processes that code images: the codec also serves the hub and the
    # backend, which never do.
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, compression, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
    if hasattr(cv2, "IMWRITE_PNG_FILTER"):
        params += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB]
    ok, data = cv2.imencode(".png", np.ascontiguousarray(image), params)
    if not ok:
        raise MessageError(f"OpenCV could not encode a {image.dtype} {image.shape} image as PNG")
    return data.tobytes()


def encode_image(image: np.ndarray, encoding: ImageEncodingName, png_compression: int) -> bytes:
    """The bytes of a uint8 grey image as a sensor frame carries it: raw rows, or PNG."""
    return png_bytes(image, png_compression) if encoding == "png" else image.tobytes()


def decode_image(data: bytes, encoding: int, shape: tuple[int, int], name: str) -> np.ndarray:
    """The read-only uint8 (height, width) image of a sensor frame's bytes field ``name``; MessageError if
    they do not hold one of that shape."""
    if encoding == pb.IMAGE_ENCODING_RAW:
        return unpack(data, "u1", shape, name)
    if encoding == pb.IMAGE_ENCODING_PNG_APART:
        raise MessageError(
            f"{name}: the image is stored apart from the message, on a recording's camera channels; "
            "read the recording with zenslam.service.mcap_io, which puts the images back"
        )
    if encoding != pb.IMAGE_ENCODING_PNG:
        raise MessageError(f"{name}: unknown image encoding {encoding}; the sender's zenslam is newer than this one")
    import cv2  # see png_bytes

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint8 or image.shape != shape:
        got = "undecodable bytes" if image is None else f"{image.dtype} {image.shape}"
        raise MessageError(f"{name}: the PNG holds {got}, expected uint8 {shape}; the message is corrupt")
    image.flags.writeable = False  # like the raw encoding's views on the received bytes
    return image
