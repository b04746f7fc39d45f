"""Shared packing of the bus messages: arrays in bytes fields (lengths checked), parsing, calibration,
sensor kind and rigid transforms."""

from __future__ import annotations

import numpy as np
from google.protobuf.message import DecodeError, Message

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import CalibrationError, MessageError
from zenslam.geometry import R_to_quat_wxyz, quat_wxyz_to_R
from zenslam.schemas import zenslam_pb2 as pb

# Sensor kind -> its protobuf code.
SENSOR_CODES: dict[str, int] = {"mono": pb.SENSOR_KIND_MONO, "stereo": pb.SENSOR_KIND_STEREO, "rgbd": pb.SENSOR_KIND_RGBD}


def pack(array: np.ndarray, dtype: str, shape_tail: tuple[int, ...], name: str) -> bytes:
    """``array`` as the little-endian bytes of a bytes field: rows of ``shape_tail`` in ``dtype``; MessageError naming ``name`` otherwise."""
    a = np.asarray(array)
    if a.shape[1:] != shape_tail:
        raise MessageError(f"{name} must have shape (N, {', '.join(map(str, shape_tail))}), got {a.shape}")
    return np.ascontiguousarray(a, dtype=dtype).tobytes()


def unpack(data: bytes, dtype: str, shape: tuple[int, ...], name: str) -> np.ndarray:
    """A read-only ``dtype`` array of ``shape`` viewing bytes field ``name``; MessageError when the length disagrees."""
    dt = np.dtype(dtype)
    expected = int(np.prod(shape)) * dt.itemsize
    if len(data) != expected:
        raise MessageError(f"field {name}: expected {expected} bytes for {dt} {shape}, got {len(data)}; sender and receiver disagree")
    return np.frombuffer(data, dtype=dt).reshape(shape)


def parse(cls: type[Message], data: bytes) -> Message:
    """``data`` parsed as protobuf message ``cls``; MessageError when it is not one."""
    msg = cls()
    try:
        msg.ParseFromString(bytes(data))
    except DecodeError as exc:
        raise MessageError(f"cannot decode {len(data)} bytes as {cls.DESCRIPTOR.full_name}: {exc}") from exc
    return msg


def calibration_to_pb(calibration: PinholeCalibration, out: pb.Calibration) -> None:
    """Write ``calibration`` (pixels; baseline in metres, if any) into ``out``."""
    out.fx, out.fy, out.cx, out.cy = calibration.fx, calibration.fy, calibration.cx, calibration.cy
    out.width, out.height = calibration.width, calibration.height
    if calibration.baseline_m is not None:
        out.baseline_m = calibration.baseline_m


def calibration_from_pb(msg: pb.Calibration, where: str = "message") -> PinholeCalibration:
    """The calibration of ``msg``; MessageError naming ``where`` when it is invalid."""
    baseline = msg.baseline_m if msg.HasField("baseline_m") else None
    try:
        return PinholeCalibration(msg.fx, msg.fy, msg.cx, msg.cy, msg.width, msg.height, baseline)
    except CalibrationError as exc:
        raise MessageError(f"{where}: {exc}") from exc


def sensor_from_pb(value: int, where: str) -> SensorKind:
    """The sensor kind of protobuf code ``value``; MessageError naming ``where`` for an unknown code."""
    for name, code in SENSOR_CODES.items():
        if code == value:
            return name  # type: ignore[return-value]
    raise MessageError(f"{where}: sensor kind {value} is not mono, stereo or rgbd")


def transform_to_pb(T: np.ndarray, out: pb.RigidTransform) -> None:
    """Write the 4x4 rigid transform ``T`` into ``out`` (translation, quaternion w, x, y, z)."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise MessageError(f"a pose must be a 4x4 transform, got shape {T.shape}")
    out.tx, out.ty, out.tz = (float(v) for v in T[:3, 3])
    out.qw, out.qx, out.qy, out.qz = (float(v) for v in R_to_quat_wxyz(T[:3, :3]))


def transform_from_pb(msg: pb.RigidTransform) -> np.ndarray:
    """The 4x4 rigid transform of ``msg``."""
    T = np.eye(4)
    T[:3, :3] = quat_wxyz_to_R(np.array([msg.qw, msg.qx, msg.qy, msg.qz]))
    T[:3, 3] = (msg.tx, msg.ty, msg.tz)
    return T
