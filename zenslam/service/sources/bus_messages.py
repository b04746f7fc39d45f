"""What a bus source takes from another program's messages: images, camera calibrations, whole frames.

A *message family* (``zenoh:`` takes foxglove and zenslam protobuf messages, see zenoh_family.py;
``ros2:`` would take rmw_zenoh's CDR messages) says which key expressions to subscribe to, which
*role* each plays in a frame (the left image, the right camera's calibration, ...), and decodes a
payload into one of the types here. Everything after that (pairing images by stamp, choosing the
sensor, building the calibration, dropping what tracking cannot keep up with) is shared by every
family (frame_assembly.py, bus_source.py), so a new family is one small module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, MessageError
from zenslam.schemas import codec

# What a message is for: ``frame`` a whole zenslam.SensorFrame (calibration and sensor inside);
# ``image``/``depth``/``calibration`` a mono or RGB-D camera; ``left_*``/``right_*`` a stereo pair.
Role = Literal["frame", "image", "depth", "calibration", "left_image", "right_image", "left_calibration", "right_calibration"]
IMAGE_ROLES: tuple[Role, ...] = ("image", "left_image", "right_image", "depth")
CALIBRATION_ROLES: tuple[Role, ...] = ("calibration", "left_calibration", "right_calibration")


@dataclass(frozen=True)
class BusImage:
    """One decoded image: ``pixels`` uint8 HxW grey, or float32 HxW metres (0: unknown) for depth."""

    stamp_ns: int
    pixels: np.ndarray


@dataclass(frozen=True)
class BusCalibration:
    """A camera's calibration as ROS and foxglove state it (K, D, P of sensor_msgs/CameraInfo).

    ``P`` (3x4) is the projection of the rectified image: its intrinsics are the ones zenslam uses,
    and a right camera's ``P[0, 3]`` is ``-fx * baseline``. An all-zero ``P`` means none was given:
    then ``K`` is used, if the distortion ``D`` is zero.
    """

    stamp_ns: int
    width: int  # pixels
    height: int  # pixels
    K: np.ndarray  # (3, 3)
    D: np.ndarray  # (n,) distortion coefficients
    P: np.ndarray  # (3, 4)


BusMessage = BusImage | BusCalibration | codec.FrameMessage


class MessageFamily(Protocol):
    """A kind of bus input: which keys carry which role, and how their payloads decode."""

    @property
    def name(self) -> str:
        """The spec it was made from, e.g. ``zenoh:cam/kitti`` (for logs and errors)."""
        ...

    def subscriptions(self) -> dict[str, Role]:
        """Key expression -> the role of the messages on it."""
        ...

    def liveliness_key(self) -> str:
        """Key expression of the publishers' liveliness tokens: the stream ends when they all go."""
        ...

    def decode(self, role: Role, key: str, payload: bytes, schema: str | None) -> BusMessage | codec.EndOfStream:
        """The message on ``key`` (``schema``: the zenoh encoding's schema, None if it has none);
        MessageError (or a protobuf/OpenCV error) when the payload is not a valid message."""
        ...


def nonzero(values: np.ndarray) -> bool:
    """True when any of ``values`` is not zero."""
    return bool(np.any(np.asarray(values, dtype=float) != 0.0))


def check_calibration_arrays(K: np.ndarray, D: np.ndarray, P: np.ndarray, where: str) -> None:
    """MessageError naming ``where`` unless K, D and P are finite."""
    for name, values in (("K", K), ("D", D), ("P", P)):
        if not np.all(np.isfinite(values)):
            raise MessageError(f"{where}: the calibration's {name} holds non-finite values")


def pinhole_of(calibration: BusCalibration, where: str) -> PinholeCalibration:
    """The rectified intrinsics of ``calibration`` (from P, else from K when there is no distortion),
    without a baseline; CalibrationError naming ``where`` when they are unusable."""
    P, K = np.asarray(calibration.P, float), np.asarray(calibration.K, float)
    if nonzero(P):
        fx, fy, cx, cy = P[0, 0], P[1, 1], P[0, 2], P[1, 2]
    elif nonzero(calibration.D):
        raise CalibrationError(
            f"{where}: the calibration has distortion D={np.asarray(calibration.D).tolist()} and no rectified "
            "projection P; zenslam needs rectified images: publish rectified images with their P, or give "
            "--orbslam-settings"
        )
    else:
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return PinholeCalibration(float(fx), float(fy), float(cx), float(cy), int(calibration.width), int(calibration.height))


def baseline_of(calibration: BusCalibration) -> float | None:
    """The stereo baseline in metres stated by a right camera's (or an RGB-D camera's virtual right
    camera's) ``P[0, 3] = -fx * baseline``; None when P states none."""
    P = np.asarray(calibration.P, float)
    if P[0, 0] <= 0 or P[0, 3] == 0:
        return None
    baseline = -P[0, 3] / P[0, 0]
    return float(baseline) if math.isfinite(baseline) and baseline > 0 else None


def projection_matrix(calibration: PinholeCalibration, baseline_m: float | None = None) -> np.ndarray:
    """The 3x4 P of a rectified camera; ``baseline_m`` sets ``P[0, 3] = -fx * baseline_m`` (a right camera)."""
    P = np.zeros((3, 4))
    P[:, :3] = calibration.K
    if baseline_m is not None:
        P[0, 3] = -calibration.fx * baseline_m
    return P
