"""Sensor frames (sensor/frame): images, depth, calibration and sensor kind; the forms a recording stores them in."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import CalibrationError, MessageError
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.codec.end_of_stream import EndOfStream
from zenslam.schemas.codec.images import IMAGE_ENCODING_CODES, ImageEncodingName, decode_image, encode_image, png_bytes
from zenslam.schemas.codec.packing import SENSOR_CODES, calibration_from_pb, calibration_to_pb, parse, sensor_from_pb, unpack
from zenslam.schemas.message_checks import check_frame_values
from zenslam.schemas.sensor_data import SensorFrame

DepthEncodingName = Literal["float32_m", "uint16_mm"]


@dataclass(frozen=True)
class FrameMessage:
    """A decoded sensor/frame message: the frame with the calibration and sensor kind it came with."""

    frame: SensorFrame
    calibration: PinholeCalibration
    sensor: SensorKind
    source_name: str = ""


def encode_sensor_frame(
    frame: SensorFrame,
    calibration: PinholeCalibration,
    sensor: SensorKind,
    source_name: str = "",
    depth_encoding: DepthEncodingName = "float32_m",
    image_encoding: ImageEncodingName = "raw",
    png_compression: int = 1,
) -> bytes:
    """Encode a frame (uint8 grey images, depth in metres) with its calibration for sensor/frame.

    ``depth_encoding`` "uint16_mm" rounds depth to millimetres (0 stays unknown) to halve its size.
    ``image_encoding`` "png" stores the images as lossless PNG at zlib level ``png_compression``.
    """
    left = np.asarray(frame.left)
    if left.dtype != np.uint8 or left.ndim != 2:
        raise MessageError(f"frame {frame.index}: left image must be uint8 HxW grey, got {left.dtype} {left.shape}")
    height, width = left.shape
    if (width, height) != (calibration.width, calibration.height):
        raise CalibrationError(
            f"frame {frame.index} is {width}x{height} but the calibration says {calibration.width}x{calibration.height}; "
            "fix the calibration override or the source"
        )
    msg = pb.SensorFrame(index=frame.index, stamp_ns=frame.stamp_ns, width=width, height=height, source_name=source_name)
    msg.sensor = SENSOR_CODES[sensor]
    calibration_to_pb(calibration, msg.calibration)
    msg.image_encoding = IMAGE_ENCODING_CODES[image_encoding]
    msg.left = encode_image(left, image_encoding, png_compression)
    if frame.right is not None:
        right = np.asarray(frame.right)
        if right.shape != left.shape or right.dtype != np.uint8:
            raise MessageError(f"frame {frame.index}: right image {right.dtype} {right.shape} must match left uint8 {left.shape}")
        msg.right = encode_image(right, image_encoding, png_compression)
    if frame.depth_m is not None:
        depth = np.asarray(frame.depth_m)
        if depth.shape != left.shape:
            raise MessageError(f"frame {frame.index}: depth {depth.shape} must match the image {left.shape}")
        if depth_encoding == "uint16_mm":
            mm = np.clip(np.rint(np.nan_to_num(depth, nan=0.0) * 1000.0), 0, np.iinfo(np.uint16).max)
            msg.depth_encoding, msg.depth = pb.DEPTH_ENCODING_UINT16_MM, mm.astype("<u2").tobytes()
        else:
            msg.depth_encoding, msg.depth = pb.DEPTH_ENCODING_FLOAT32_M, np.ascontiguousarray(depth, "<f4").tobytes()
    return msg.SerializeToString()


def sensor_frame_as_png(data: bytes, png_compression: int = 1) -> bytes:
    """The sensor/frame message ``data`` with its images as lossless PNG (as the recorder stores it).

    Everything else is kept as it is; an end of stream, or a frame already in PNG, comes back unchanged.
    """
    msg = parse(pb.SensorFrame, data)
    if msg.end_of_stream or msg.image_encoding == pb.IMAGE_ENCODING_PNG:
        return bytes(data)
    shape, where = (msg.height, msg.width), f"sensor frame {msg.index}"
    msg.left = png_bytes(decode_image(msg.left, msg.image_encoding, shape, f"{where} left"), png_compression)
    if msg.right:
        msg.right = png_bytes(decode_image(msg.right, msg.image_encoding, shape, f"{where} right"), png_compression)
    msg.image_encoding = pb.IMAGE_ENCODING_PNG
    return msg.SerializeToString()


def sensor_frame_images_apart(data: bytes, png_compression: int = 1) -> tuple[bytes, list[bytes]]:
    """The sensor/frame message ``data`` split for a recording that stores each image once:
    (the message without its images, IMAGE_ENCODING_PNG_APART; [left PNG, and right PNG if any]).

    Images already in PNG are kept as they are; an end of stream comes back unchanged with no images.
    ``sensor_frame_with_images`` puts them back.
    """
    msg = parse(pb.SensorFrame, sensor_frame_as_png(data, png_compression))
    if msg.end_of_stream:
        return bytes(data), []
    images = [msg.left, msg.right] if msg.right else [msg.left]
    msg.image_encoding = pb.IMAGE_ENCODING_PNG_APART
    msg.ClearField("left")
    msg.ClearField("right")
    return msg.SerializeToString(), images


def sensor_frame_with_images(data: bytes, left_png: bytes, right_png: bytes | None) -> bytes:
    """The sensor/frame message ``data`` whose images were stored apart, with them put back (IMAGE_ENCODING_PNG).

    A message that holds its images (or an end of stream) comes back unchanged.
    """
    msg = parse(pb.SensorFrame, data)
    if msg.end_of_stream or msg.image_encoding != pb.IMAGE_ENCODING_PNG_APART:
        return bytes(data)
    msg.image_encoding = pb.IMAGE_ENCODING_PNG
    msg.left = left_png
    if right_png is not None:
        msg.right = right_png
    return msg.SerializeToString()


def sensor_frame_images_are_apart(data: bytes) -> bool:
    """True when the sensor/frame message ``data`` holds no images: a recording stores them apart."""
    msg = parse(pb.SensorFrame, data)
    return not msg.end_of_stream and msg.image_encoding == pb.IMAGE_ENCODING_PNG_APART


def decode_sensor_frame(data: bytes) -> FrameMessage | EndOfStream:
    """Decode a sensor/frame message (images raw or PNG); depth comes back as float32 metres whatever its encoding."""
    msg = parse(pb.SensorFrame, data)
    if msg.end_of_stream:
        return EndOfStream(msg.count)
    shape = (msg.height, msg.width)
    where = f"sensor frame {msg.index}"
    left = decode_image(msg.left, msg.image_encoding, shape, f"{where} left")
    right = decode_image(msg.right, msg.image_encoding, shape, f"{where} right") if msg.right else None
    depth = None
    if msg.depth_encoding == pb.DEPTH_ENCODING_FLOAT32_M:
        depth = unpack(msg.depth, "<f4", shape, f"{where} depth")
    elif msg.depth_encoding == pb.DEPTH_ENCODING_UINT16_MM:
        depth = unpack(msg.depth, "<u2", shape, f"{where} depth").astype(np.float32) / np.float32(1000.0)
    frame = SensorFrame(index=msg.index, stamp_ns=msg.stamp_ns, left=left, right=right, depth_m=depth)
    calibration, sensor = calibration_from_pb(msg.calibration, where), sensor_from_pb(msg.sensor, where)
    check_frame_values(msg.index, msg.stamp_ns, shape, calibration.width, calibration.height, sensor, right is not None, depth is not None)
    return FrameMessage(frame, calibration, sensor, msg.source_name)
