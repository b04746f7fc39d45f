"""ROS 2 sensor messages to and from CDR: sensor_msgs/Image, CompressedImage, CameraInfo and Imu.

Decoders take the payload of one zenoh sample (the CDR bytes rmw_zenoh puts) and return plain
values in zenslam's conventions; anything that is not a well-formed message of the type, or an
image encoding zenslam cannot use, raises MessageError naming the topic and the type. The
encoders (for ``zenslam publish --ros2``) make what a ROS 2 camera driver publishes. The pose, path
and tf encoders zenslam publishes its results with are in ``pose_messages`` and re-exported here.

Images come out as OpenCV does them: ``mono8`` as (H, W) uint8, ``bgr8``/``rgb8`` (and colour
compressed images) as (H, W, 3) uint8 in BGR order, depth (``16UC1`` millimetres or ``32FC1``
metres) as (H, W) float32 metres with 0 where unknown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, MessageError
from zenslam.service.ros2 import cdr
from zenslam.service.ros2.pose_messages import encode_path, encode_pose_stamped, encode_tf

__all__ = [
    "RosCameraInfo", "RosImage", "RosImu", "decode_camera_info", "decode_compressed_image", "decode_image",
    "decode_imu", "encode_camera_info", "encode_compressed_image", "encode_image", "encode_path",
    "encode_pose_stamped", "encode_tf",
]

# encoding -> (numpy dtype of one channel, channels)
_ENCODINGS: dict[str, tuple[np.dtype, int]] = {
    "mono8": (np.dtype(np.uint8), 1),
    "bgr8": (np.dtype(np.uint8), 3),
    "rgb8": (np.dtype(np.uint8), 3),
    "16UC1": (np.dtype(np.uint16), 1),
    "32FC1": (np.dtype(np.float32), 1),
}
DEPTH_ENCODINGS = ("16UC1", "32FC1")
_MM_PER_M = 1000.0


@dataclass(frozen=True)
class RosImage:
    """A decoded image: ``image`` as described in the module docstring, ``encoding`` as the message said."""

    stamp_ns: int
    frame_id: str
    image: np.ndarray
    encoding: str  # the Image's encoding, or for a CompressedImage the decoded kind (mono8, bgr8 or 16UC1)

    @property
    def is_depth(self) -> bool:
        return self.encoding in DEPTH_ENCODINGS

    def grey(self) -> np.ndarray:
        """The image as (H, W) uint8 grey, what tracking takes; MessageError for a depth image."""
        if self.is_depth:
            raise MessageError(f"a {self.encoding} depth image has no grey image; subscribe to the camera's image topic")
        if self.image.ndim == 2:
            return self.image
        return cv2.cvtColor(self.image, cv2.COLOR_BGR2GRAY)


@dataclass(frozen=True)
class RosCameraInfo:
    """A decoded sensor_msgs/CameraInfo: ``k`` (3x3) and ``p`` (3x4) in pixels, ``d`` its distortion."""

    stamp_ns: int
    frame_id: str
    width: int
    height: int
    k: np.ndarray  # (3, 3) intrinsics of the raw image
    d: np.ndarray  # (N,) distortion coefficients of ``distortion_model``
    p: np.ndarray  # (3, 4) projection of the rectified image; p[0, 3] = -fx * baseline for a right camera
    distortion_model: str = ""

    def _intrinsics(self) -> tuple[float, float, float, float]:
        """fx, fy, cx, cy of the rectified image: P's when set (ROS's rectified projection), else K's."""
        source = self.p if self.p[0, 0] > 0 else self.k
        return float(source[0, 0]), float(source[1, 1]), float(source[0, 2]), float(source[1, 2])

    def calibration(self) -> PinholeCalibration:
        """zenslam's calibration of a mono camera whose images are rectified (e.g. an ``image_rect`` topic)."""
        fx, fy, cx, cy = self._intrinsics()
        return PinholeCalibration(fx, fy, cx, cy, self.width, self.height)

    def stereo_calibration(self, right: RosCameraInfo) -> PinholeCalibration:
        """zenslam's calibration of a rectified stereo pair: this (left) camera's intrinsics and the
        baseline in metres from the right camera's projection (P[0, 3] = -fx * baseline)."""
        problems = []
        if self.p[0, 0] <= 0 or right.p[0, 0] <= 0:
            problems.append("both CameraInfo messages must carry the rectified projection P (P[0,0] > 0)")
        elif not math.isclose(self.p[0, 0], right.p[0, 0], rel_tol=1e-3):
            problems.append(f"the rectified focal lengths differ (left {self.p[0, 0]:g}, right {right.p[0, 0]:g} px)")
        elif right.p[0, 3] >= 0:
            problems.append(f"the right camera's P[0,3] = {right.p[0, 3]:g} must be -fx * baseline (negative)")
        if (self.width, self.height) != (right.width, right.height):
            problems.append(f"image sizes differ ({self.width}x{self.height} vs {right.width}x{right.height})")
        if problems:
            raise CalibrationError(
                f"cannot make a stereo calibration from CameraInfo frames {self.frame_id!r} and {right.frame_id!r}: "
                + "; ".join(problems)
            )
        fx, fy, cx, cy = self._intrinsics()
        baseline_m = -float(right.p[0, 3]) / float(right.p[0, 0])
        return PinholeCalibration(fx, fy, cx, cy, self.width, self.height, baseline_m=baseline_m)


@dataclass(frozen=True)
class RosImu:
    """A decoded sensor_msgs/Imu in its ``frame_id``: gyro rad/s, accelerometer m/s^2."""

    stamp_ns: int
    frame_id: str
    orientation_xyzw: np.ndarray  # (4,); all zeros or covariance[0] = -1 when the IMU gives none
    gyro_rad_s: np.ndarray  # (3,)
    accel_m_s2: np.ndarray  # (3,)


def _pixels(msg: Any, topic: str | None) -> np.ndarray:
    """The (H, W[, C]) array of an Image message's data, checked against its size, step and encoding."""
    if msg.encoding not in _ENCODINGS:
        raise MessageError(
            f"{cdr.where(topic)}: sensor_msgs/msg/Image encoding {msg.encoding!r} is not supported; "
            f"publish one of {', '.join(_ENCODINGS)}"
        )
    dtype, channels = _ENCODINGS[msg.encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = width * channels * dtype.itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if height < 1 or width < 1 or step < row_bytes or data.size < step * height:
        raise MessageError(
            f"{cdr.where(topic)}: sensor_msgs/msg/Image of {width}x{height} {msg.encoding} with step {step} "
            f"needs {row_bytes} <= step and {step * height} bytes of data, got {data.size}"
        )
    rows = data[: step * height].reshape(height, step)[:, :row_bytes]
    order = ">" if msg.is_bigendian and dtype.itemsize > 1 else "<"
    pixels = np.ascontiguousarray(rows).view(dtype.newbyteorder(order)).astype(dtype, copy=True)
    return pixels.reshape(height, width, channels) if channels > 1 else pixels.reshape(height, width)


def _to_zenslam(pixels: np.ndarray, encoding: str) -> np.ndarray:
    """Pixels of ``encoding`` in zenslam's conventions (BGR colour, float32 metres of depth, 0 unknown)."""
    if encoding == "rgb8":
        return np.ascontiguousarray(pixels[:, :, ::-1])
    if encoding == "16UC1":
        return pixels.astype(np.float32) / np.float32(_MM_PER_M)
    if encoding == "32FC1":
        return np.where(np.isfinite(pixels) & (pixels > 0), pixels, np.float32(0.0)).astype(np.float32)
    return pixels


def decode_image(payload: bytes, topic: str | None = None) -> RosImage:
    """A sensor_msgs/msg/Image payload as a RosImage (mono8, bgr8, rgb8, 16UC1 mm or 32FC1 m)."""
    msg = cdr.deserialize(payload, cdr.IMAGE, topic)
    pixels = _pixels(msg, topic)
    return RosImage(cdr.stamp_ns_of(msg.header.stamp), msg.header.frame_id, _to_zenslam(pixels, msg.encoding), msg.encoding)


def decode_compressed_image(payload: bytes, topic: str | None = None) -> RosImage:
    """A sensor_msgs/msg/CompressedImage payload (PNG or JPEG, as image_transport's compressed plugin
    sends) as a RosImage: 8-bit grey as mono8, colour as bgr8, 16-bit grey PNG as depth in mm."""
    msg = cdr.deserialize(payload, cdr.COMPRESSED_IMAGE, topic)
    if "compresseddepth" in msg.format.lower():
        raise MessageError(
            f"{cdr.where(topic)}: CompressedImage format {msg.format!r} (compressedDepth) is not supported; "
            "publish the depth as a sensor_msgs/msg/Image or a plain PNG CompressedImage"
        )
    data = np.asarray(msg.data, dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None:
        raise MessageError(
            f"{cdr.where(topic)}: the {data.size} bytes of a CompressedImage (format {msg.format!r}) are not a PNG or JPEG image"
        )
    if image.dtype == np.uint16 and image.ndim == 2:
        encoding = "16UC1"
    elif image.dtype != np.uint8:
        raise MessageError(f"{cdr.where(topic)}: CompressedImage decodes to {image.dtype} pixels; send 8-bit images or 16-bit depth")
    elif image.ndim == 2:
        encoding = "mono8"
    else:
        encoding = "bgr8"
        image = image[:, :, :3] if image.shape[2] >= 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    stamp_ns = cdr.stamp_ns_of(msg.header.stamp)
    return RosImage(stamp_ns, msg.header.frame_id, _to_zenslam(np.ascontiguousarray(image), encoding), encoding)


def decode_camera_info(payload: bytes, topic: str | None = None) -> RosCameraInfo:
    """A sensor_msgs/msg/CameraInfo payload as a RosCameraInfo."""
    msg = cdr.deserialize(payload, cdr.CAMERA_INFO, topic)
    k, p = np.asarray(msg.k, dtype=float), np.asarray(msg.p, dtype=float)
    if k.size != 9 or p.size != 12 or not (np.isfinite(k).all() and np.isfinite(p).all()):
        raise MessageError(f"{cdr.where(topic)}: sensor_msgs/msg/CameraInfo has a non-finite or misshapen K or P")
    return RosCameraInfo(
        stamp_ns=cdr.stamp_ns_of(msg.header.stamp),
        frame_id=msg.header.frame_id,
        width=int(msg.width),
        height=int(msg.height),
        k=k.reshape(3, 3).copy(),
        d=np.asarray(msg.d, dtype=float).copy(),
        p=p.reshape(3, 4).copy(),
        distortion_model=msg.distortion_model,
    )


def decode_imu(payload: bytes, topic: str | None = None) -> RosImu:
    """A sensor_msgs/msg/Imu payload as a RosImu."""
    msg = cdr.deserialize(payload, cdr.IMU, topic)
    q, w, a = msg.orientation, msg.angular_velocity, msg.linear_acceleration
    return RosImu(
        stamp_ns=cdr.stamp_ns_of(msg.header.stamp),
        frame_id=msg.header.frame_id,
        orientation_xyzw=np.array([q.x, q.y, q.z, q.w], dtype=float),
        gyro_rad_s=np.array([w.x, w.y, w.z], dtype=float),
        accel_m_s2=np.array([a.x, a.y, a.z], dtype=float),
    )


def _encoding_of(image: np.ndarray) -> str:
    if image.dtype == np.uint8 and image.ndim == 2:
        return "mono8"
    if image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3:
        return "bgr8"
    if image.dtype == np.uint16 and image.ndim == 2:
        return "16UC1"
    if image.dtype == np.float32 and image.ndim == 2:
        return "32FC1"
    raise MessageError(
        f"cannot publish a {image.dtype} image of shape {image.shape}: give (H, W) uint8 grey, (H, W, 3) uint8 BGR, "
        "(H, W) uint16 depth in mm or (H, W) float32 depth in metres"
    )


def encode_image(stamp_ns: int, frame_id: str, image: np.ndarray) -> bytes:
    """A sensor_msgs/msg/Image of ``image``: uint8 grey as mono8, uint8 BGR as bgr8, uint16 depth (mm)
    as 16UC1, float32 depth (m) as 32FC1; little-endian, rows unpadded."""
    image = np.ascontiguousarray(image)
    encoding = _encoding_of(image)
    height, width = image.shape[:2]
    msg = cdr.msg_class(cdr.IMAGE)(
        header=cdr.header(stamp_ns, frame_id), height=height, width=width, encoding=encoding, is_bigendian=0,
        step=image.strides[0], data=image.astype(image.dtype.newbyteorder("<"), copy=False).reshape(-1).view(np.uint8),
    )
    return cdr.serialize(msg, cdr.IMAGE)


def encode_compressed_image(stamp_ns: int, frame_id: str, image: np.ndarray, image_format: str = "png") -> bytes:
    """A sensor_msgs/msg/CompressedImage of ``image`` (grey or BGR uint8) as ``png`` or ``jpeg``."""
    if image_format not in ("png", "jpeg"):
        raise MessageError(f"CompressedImage format {image_format!r} must be 'png' or 'jpeg'")
    ok, data = cv2.imencode(".png" if image_format == "png" else ".jpg", image)
    if not ok:
        raise MessageError(f"OpenCV cannot encode a {image.dtype} image of shape {image.shape} as {image_format}")
    msg = cdr.msg_class(cdr.COMPRESSED_IMAGE)(
        header=cdr.header(stamp_ns, frame_id), format=image_format, data=np.asarray(data, dtype=np.uint8).reshape(-1)
    )
    return cdr.serialize(msg, cdr.COMPRESSED_IMAGE)


def encode_camera_info(stamp_ns: int, frame_id: str, calibration: PinholeCalibration, right: bool = False) -> bytes:
    """The sensor_msgs/msg/CameraInfo of rectified, distortion-free images of ``calibration``; for the
    right camera of a stereo pair (``right``) P[0, 3] = -fx * baseline, as ROS's stereo convention has it."""
    fx, fy, cx, cy = calibration.fx, calibration.fy, calibration.cx, calibration.cy
    tx = -calibration.bf if right else 0.0  # bf raises for a mono calibration
    msg = cdr.msg_class(cdr.CAMERA_INFO)(
        header=cdr.header(stamp_ns, frame_id),
        height=calibration.height,
        width=calibration.width,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=np.array([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]),
        r=np.eye(3).reshape(-1),
        p=np.array([fx, 0.0, cx, tx, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]),
        binning_x=0,
        binning_y=0,
        roi=cdr.msg_class("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )
    return cdr.serialize(msg, cdr.CAMERA_INFO)
