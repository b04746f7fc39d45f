"""foxglove.RawImage, foxglove.CompressedImage and foxglove.CameraCalibration <-> images and calibrations.

Decoding checks every size before it allocates or decodes anything: a payload from another program
may be truncated, corrupt or hostile, and must fail here with MessageError, never take the process
down. Images become uint8 grey (colour is converted); depth images (``depth`` role) become float32
metres from ``32FC1`` (metres) or ``16UC1``/``mono16`` (millimetres). Compressed images are PNG or
JPEG (their header's size is checked before decoding).
"""

from __future__ import annotations

import struct

import cv2
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf.message import DecodeError, Message

from zenslam.camera import PinholeCalibration
from zenslam.errors import MessageError
from zenslam.schemas import codec
from zenslam.service.sources.bus_messages import BusCalibration, BusImage, check_calibration_arrays, projection_matrix

RAW_IMAGE = "foxglove.RawImage"
COMPRESSED_IMAGE = "foxglove.CompressedImage"
CAMERA_CALIBRATION = "foxglove.CameraCalibration"

MAX_SIDE_PX = 16384  # largest width or height accepted, pixels
MAX_PIXELS = 50_000_000  # largest image accepted, pixels

# RawImage encoding -> (bytes per pixel, channels); grey, colour and depth encodings of ROS/foxglove.
_RAW_ENCODINGS: dict[str, tuple[int, int]] = {
    "mono8": (1, 1), "8UC1": (1, 1), "rgb8": (3, 3), "bgr8": (3, 3), "rgba8": (4, 4), "bgra8": (4, 4),
    "16UC1": (2, 1), "mono16": (2, 1), "32FC1": (4, 1),
}  # fmt: skip
_TO_GREY = {"rgb8": cv2.COLOR_RGB2GRAY, "bgr8": cv2.COLOR_BGR2GRAY, "rgba8": cv2.COLOR_RGBA2GRAY, "bgra8": cv2.COLOR_BGRA2GRAY}
_DEPTH_ENCODINGS = ("32FC1", "16UC1", "mono16")


def _parse(cls: type[Message], payload: bytes, where: str) -> Message:
    message = cls()
    try:
        message.ParseFromString(payload)
    except DecodeError as exc:
        raise MessageError(f"{where}: not a {cls.DESCRIPTOR.full_name} message ({exc})") from exc
    return message


def _stamp_ns(message: Message) -> int:
    stamp = message.timestamp
    return int(stamp.seconds) * 1_000_000_000 + int(stamp.nanos)


def _check_size(width: int, height: int, where: str) -> None:
    if not (0 < width <= MAX_SIDE_PX and 0 < height <= MAX_SIDE_PX and width * height <= MAX_PIXELS):
        raise MessageError(f"{where}: image size {width}x{height} is empty or larger than {MAX_SIDE_PX} px a side / {MAX_PIXELS} px")


def decode_raw_image(payload: bytes, depth: bool, where: str) -> BusImage:
    """A foxglove.RawImage as a grey uint8 image, or (``depth``) a float32 depth image in metres."""
    msg = _parse(RawImage, payload, where)
    width, height, step, encoding = int(msg.width), int(msg.height), int(msg.step), msg.encoding
    if encoding not in _RAW_ENCODINGS or (encoding in _DEPTH_ENCODINGS) != depth:
        wanted = "32FC1, 16UC1 or mono16" if depth else "mono8, 8UC1, rgb8, bgr8, rgba8 or bgra8"
        raise MessageError(f"{where}: RawImage encoding {encoding!r} is not one of {wanted}")
    _check_size(width, height, where)
    pixel_bytes, channels = _RAW_ENCODINGS[encoding]
    if step < width * pixel_bytes or len(msg.data) != step * height:
        raise MessageError(
            f"{where}: RawImage of {width}x{height} {encoding} with step {step} needs {step * height} bytes "
            f"(step >= {width * pixel_bytes}), got {len(msg.data)}"
        )
    dtype = {1: np.uint8, 2: np.dtype("<u2"), 3: np.uint8, 4: np.uint8 if channels == 4 else np.dtype("<f4")}[pixel_bytes]
    rows = np.frombuffer(msg.data, np.uint8).reshape(height, step)[:, : width * pixel_bytes]
    pixels = np.ascontiguousarray(rows).view(dtype).reshape((height, width, channels) if channels > 1 else (height, width))
    if encoding in _TO_GREY:
        pixels = cv2.cvtColor(pixels, _TO_GREY[encoding])
    elif encoding == "32FC1":
        pixels = np.where(np.isfinite(pixels) & (pixels > 0), pixels, 0).astype(np.float32)
    elif depth:
        pixels = pixels.astype(np.float32) / np.float32(1000.0)
    return BusImage(_stamp_ns(msg), pixels)


def _compressed_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) stated by a PNG or JPEG header, or None when ``data`` is neither."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24 and data[12:16] == b"IHDR":
        width, height = struct.unpack(">II", data[16:24])
        return width, height
    if data[:2] != b"\xff\xd8":
        return None
    at = 2
    while at + 9 <= len(data):  # JPEG segments up to the frame header (SOF0..SOF15 but DHT, JPG, DAC)
        if data[at] != 0xFF:
            return None
        marker, length = data[at + 1], struct.unpack(">H", data[at + 2 : at + 4])[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            height, width = struct.unpack(">HH", data[at + 5 : at + 9])
            return width, height
        at += 2 + length
    return None


def decode_compressed_image(payload: bytes, depth: bool, where: str) -> BusImage:
    """A foxglove.CompressedImage (PNG or JPEG) as a grey uint8 image, or (``depth``) a 16-bit PNG
    of millimetres as float32 metres."""
    msg = _parse(CompressedImage, payload, where)
    data = bytes(msg.data)
    size = _compressed_size(data)
    if size is None:
        raise MessageError(f"{where}: CompressedImage format {msg.format!r} holds neither a PNG nor a JPEG image")
    _check_size(*size, where)
    flags = cv2.IMREAD_UNCHANGED if depth else cv2.IMREAD_GRAYSCALE
    pixels = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if pixels is None or pixels.ndim != 2 or (pixels.shape[1], pixels.shape[0]) != size:
        raise MessageError(f"{where}: the CompressedImage ({msg.format!r}) cannot be decoded to a {size[0]}x{size[1]} image")
    if depth:
        if pixels.dtype != np.uint16:
            raise MessageError(f"{where}: a compressed depth image must be a 16-bit PNG of millimetres, got {pixels.dtype}")
        pixels = pixels.astype(np.float32) / np.float32(1000.0)
    return BusImage(_stamp_ns(msg), pixels)


def decode_camera_calibration(payload: bytes, where: str) -> BusCalibration:
    """A foxglove.CameraCalibration (K 3x3, D, P 3x4 row-major, as ROS's CameraInfo)."""
    msg = _parse(CameraCalibration, payload, where)
    _check_size(int(msg.width), int(msg.height), where)
    if len(msg.K) != 9 or len(msg.P) not in (0, 12) or len(msg.D) > 16:
        raise MessageError(f"{where}: CameraCalibration needs 9 K values and 12 P values (or none), got {len(msg.K)} and {len(msg.P)}")
    K = np.array(msg.K, float).reshape(3, 3)
    P = np.array(msg.P, float).reshape(3, 4) if len(msg.P) else np.zeros((3, 4))
    D = np.array(msg.D, float)
    check_calibration_arrays(K, D, P, where)
    return BusCalibration(_stamp_ns(msg), int(msg.width), int(msg.height), K, D, P)


def _timestamp(message: Message, stamp_ns: int) -> None:
    message.timestamp.seconds, message.timestamp.nanos = divmod(int(stamp_ns), 1_000_000_000)


def encode_raw_image(stamp_ns: int, pixels: np.ndarray, frame_id: str) -> bytes:
    """A foxglove.RawImage of a uint8 grey image (``mono8``) or a float32 depth image in metres (``32FC1``)."""
    pixels = np.ascontiguousarray(pixels)
    if pixels.dtype == np.uint8:
        encoding, data = "mono8", pixels.tobytes()
    elif pixels.dtype == np.float32:
        encoding, data = "32FC1", pixels.astype("<f4").tobytes()
    else:
        raise MessageError(f"a RawImage of {pixels.dtype} pixels is not supported: give uint8 grey or float32 metres")
    height, width = pixels.shape
    msg = RawImage(frame_id=frame_id, width=width, height=height, encoding=encoding, step=len(data) // height, data=data)
    _timestamp(msg, stamp_ns)
    return msg.SerializeToString()


def encode_png_image(stamp_ns: int, pixels: np.ndarray, frame_id: str) -> bytes:
    """A foxglove.CompressedImage holding a lossless PNG of a uint8 grey image."""
    msg = CompressedImage(frame_id=frame_id, format="png", data=codec.png_bytes(pixels))
    _timestamp(msg, stamp_ns)
    return msg.SerializeToString()


def encode_camera_calibration(stamp_ns: int, calibration: PinholeCalibration, frame_id: str, baseline_m: float | None = None) -> bytes:
    """A foxglove.CameraCalibration of a rectified camera (no distortion); ``baseline_m`` puts
    ``-fx * baseline_m`` in ``P[0][3]``, as a right camera's calibration states its baseline."""
    msg = CameraCalibration(
        frame_id=frame_id, width=calibration.width, height=calibration.height, distortion_model="plumb_bob",
        D=[0.0] * 5, K=calibration.K.ravel().tolist(), R=np.eye(3).ravel().tolist(),
        P=projection_matrix(calibration, baseline_m).ravel().tolist(),
    )  # fmt: skip
    _timestamp(msg, stamp_ns)
    return msg.SerializeToString()
