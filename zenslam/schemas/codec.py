"""The only encoder/decoder of zenslam bus messages: numpy arrays and dataclasses <-> protobuf bytes.

Arrays travel as raw little-endian ``bytes`` fields (see zenslam.proto for each field's dtype
and shape); decoding checks every length against the counts in the message, so a truncated or
mismatched message fails here with the field's name rather than deep inside a stage. Decoded
arrays are read-only views on the received bytes (PNG-encoded images: read-only decoded copies).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from google.protobuf.message import DecodeError, Message

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import CalibrationError, MessageError, ZenslamError
from zenslam.geometry import R_to_quat_wxyz, quat_wxyz_to_R
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.schemas.message_checks import check_frame_values, check_keyframe_values, check_map_update_values
from zenslam.schemas.relocalisation import (
    MapKeyframe,
    MapPoints,
    RelocalisationCandidate,
    RelocalisationCandidates,
    RelocalisationQuery,
)
from zenslam.schemas.sensor_data import SensorFrame

# Schema names: the protobuf full names, also used as the zenoh encoding schema and MCAP schema.
SENSOR_FRAME = "zenslam.SensorFrame"
TRACKING_STATE = "zenslam.TrackingState"
KEYFRAME = "zenslam.Keyframe"
MAP_UPDATE = "zenslam.MapUpdate"
STAGE_STATUS = "zenslam.StageStatus"
KEYFRAME_TRAJECTORY = "zenslam.KeyframeTrajectory"
MAP_SNAPSHOT = "zenslam.MapSnapshot"
LOOP = "zenslam.Loop"
RELOCALISATION_QUERY = "zenslam.RelocalisationQuery"
RELOCALISATION_CANDIDATES = "zenslam.RelocalisationCandidates"
POSE_IN_FRAME = "foxglove.PoseInFrame"

MESSAGE_CLASSES: dict[str, type[Message]] = {
    SENSOR_FRAME: pb.SensorFrame,
    TRACKING_STATE: pb.TrackingState,
    KEYFRAME: pb.Keyframe,
    MAP_UPDATE: pb.MapUpdate,
    STAGE_STATUS: pb.StageStatus,
    KEYFRAME_TRAJECTORY: pb.KeyframeTrajectory,
    MAP_SNAPSHOT: pb.MapSnapshot,
    LOOP: pb.Loop,
    RELOCALISATION_QUERY: pb.RelocalisationQuery,
    RELOCALISATION_CANDIDATES: pb.RelocalisationCandidates,
    POSE_IN_FRAME: PoseInFrame,
}

TrackingStateName = Literal["ok", "lost", "initializing"]
StageStateName = Literal["starting", "running", "finished", "failed"]
DepthEncodingName = Literal["float32_m", "uint16_mm"]
ImageEncodingName = Literal["raw", "png"]

_SENSORS: dict[str, int] = {"mono": pb.SENSOR_KIND_MONO, "stereo": pb.SENSOR_KIND_STEREO, "rgbd": pb.SENSOR_KIND_RGBD}
_TRACKING: dict[str, int] = {
    "ok": pb.TRACKING_STATE_OK,
    "lost": pb.TRACKING_STATE_LOST,
    "initializing": pb.TRACKING_STATE_INITIALIZING,
}
_STAGE: dict[str, int] = {
    "starting": pb.STAGE_STATE_STARTING,
    "running": pb.STAGE_STATE_RUNNING,
    "finished": pb.STAGE_STATE_FINISHED,
    "failed": pb.STAGE_STATE_FAILED,
}
_IMAGE_ENCODINGS: dict[str, int] = {"raw": pb.IMAGE_ENCODING_RAW, "png": pb.IMAGE_ENCODING_PNG}
_NS_PER_S = 1_000_000_000

# Element type and shape of one row of every array that travels in a bytes field, per protobuf
# message type (the row count follows from the field's length); zenslam.proto states the same.
ArrayLayout = tuple[str, tuple[int, ...]]
ARRAY_FIELDS: dict[str, dict[str, ArrayLayout]] = {
    KEYFRAME: {
        "keypoints_px": ("<f4", (2,)), "levels": ("<i2", ()), "angles_deg": ("<f4", ()), "right_u": ("<f4", ()),
        "depth_m": ("<f4", ()), "descriptors": ("u1", (32,)), "map_point_ids": ("<i8", ()), "scale_factors": ("<f8", ()),
        "new_point_ids": ("<i8", ()), "new_points_world": ("<f8", (3,)),
    },
    "zenslam.KeyframeCorrection": {"map_point_ids": ("<i8", ())},
    MAP_UPDATE: {
        "point_ids": ("<i8", ()), "p_world": ("<f8", (3,)), "descriptors": ("u1", (32,)), "normals": ("<f8", (3,)),
        "min_distance_m": ("<f8", ()), "max_distance_m": ("<f8", ()), "removed_point_ids": ("<i8", ()),
        "removed_keyframe_ids": ("<i8", ()), "normals_f32": ("<f4", (3,)), "min_distance_m_f32": ("<f4", ()),
        "max_distance_m_f32": ("<f4", ()),
    },
    KEYFRAME_TRAJECTORY: {
        "keyframe_ids": ("<i8", ()), "stamps_ns": ("<i8", ()), "T_world_cam": ("<f8", (4, 4)),
        "culled_keyframe_ids": ("<i8", ()), "culled_stamps_ns": ("<i8", ()), "culled_T_world_cam": ("<f8", (4, 4)),
    },  # fmt: skip
    MAP_SNAPSHOT: {"point_ids": ("<i8", ()), "p_world": ("<f8", (3,))},
    RELOCALISATION_QUERY: {"word_ids": ("<i8", ()), "weights": ("<f8", ())},
    "zenslam.MapKeyframe": {
        "keypoints_px": ("<f4", (2,)), "levels": ("<i2", ()), "angles_deg": ("<f4", ()), "right_u": ("<f4", ()),
        "depth_m": ("<f4", ()), "descriptors": ("u1", (32,)), "map_point_ids": ("<i8", ()), "scale_factors": ("<f8", ()),
    },
    "zenslam.RelocalisationCandidate": {"neighbour_ids": ("<i8", ())},
    RELOCALISATION_CANDIDATES: {
        "point_ids": ("<i8", ()), "p_world": ("<f8", (3,)), "descriptors": ("u1", (32,)), "normals": ("<f8", (3,)),
        "min_distance_m": ("<f8", ()), "max_distance_m": ("<f8", ()),
    },
}  # fmt: skip


@dataclass(frozen=True)
class EndOfStream:
    """The last message of a stream; ``count`` data messages were sent before it."""

    count: int


@dataclass(frozen=True)
class FrameMessage:
    """A decoded sensor/frame message: the frame with the calibration and sensor kind it came with."""

    frame: SensorFrame
    calibration: PinholeCalibration
    sensor: SensorKind
    source_name: str = ""


@dataclass(frozen=True, slots=True)  # slots: one per frame, and tools hold a run's worth
class TrackingStateMessage:
    """The outcome of tracking one frame (frontend/state)."""

    index: int
    stamp_ns: int
    state: TrackingStateName
    lost_reason: str | None = None
    n_tracked: int = 0
    timings_ms: dict[str, float] = field(default_factory=dict)  # per step, milliseconds
    has_pose: bool = False  # a frontend/pose message was sent for this frame
    keyframe_id: int = -1  # the keyframe made at this frame, -1 if none
    # The keyframe the pose is kept relative to (-1 none) and the camera in its frame (4x4, as tracked).
    reference_keyframe_id: int = -1
    T_reference_cam: np.ndarray | None = None
    relocalised: bool = False  # tracking was lost (or, localising, on visual odometry) before this frame and found the map again here


@dataclass(frozen=True)
class KeyframeMessage:
    """A keyframe on frontend/keyframe: N keypoints, M new map points, L pyramid levels."""

    id: int
    stamp_ns: int
    frame_index: int
    T_world_cam: np.ndarray  # (4, 4)
    calibration: PinholeCalibration
    sensor: SensorKind
    keypoints_px: np.ndarray  # (N, 2) float32, level-0 pixels
    levels: np.ndarray  # (N,) int16
    angles_deg: np.ndarray  # (N,) float32
    right_u: np.ndarray  # (N,) float32 pixels, -1 if none
    depth_m: np.ndarray  # (N,) float32 metres, -1 if none
    descriptors: np.ndarray  # (N, 32) uint8
    map_point_ids: np.ndarray  # (N,) int64, -1 if none
    scale_factors: np.ndarray  # (L,) float64
    new_point_ids: np.ndarray  # (M,) int64
    new_points_world: np.ndarray  # (M, 3) float64 metres


@dataclass(frozen=True)
class StampedPose:
    """A camera pose at a time: T_world_cam maps camera to ``frame_id`` coordinates."""

    stamp_ns: int
    T_world_cam: np.ndarray  # (4, 4)
    frame_id: str = "world"


@dataclass(frozen=True)
class StageStatusMessage:
    """How a stage is doing (<stage>/status)."""

    stage: str
    state: StageStateName
    processed: int = 0
    step_ms: float = 0.0  # duration of the last step, milliseconds
    queue_depth: int = 0  # messages waiting in the stage's inbox
    dropped: int = 0  # input messages skipped (live mode)
    detail: str = ""
    timings_ms: dict[str, float] = field(default_factory=dict)  # per sub-step of the last step, milliseconds
    skipped: dict[str, int] = field(default_factory=dict)  # input items not passed on so far, by reason (source: bad frames)


@dataclass(frozen=True)
class KeyframeTrajectoryMessage:
    """Keyframe poses oldest first (the backend/trajectory reply); K keyframes."""

    keyframe_ids: np.ndarray  # (K,) int64
    stamps_ns: np.ndarray  # (K,) int64
    T_world_cam: np.ndarray  # (K, 4, 4) camera -> world
    keyframes_processed: int = 0  # keyframes the backend had processed when it answered
    finished: bool = False  # the backend had processed its input's end of stream
    # Keyframes culled from the map (C), each where its spanning-tree parent's correction put it.
    culled_keyframe_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (C,) int64
    culled_stamps_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (C,) int64
    culled_T_world_cam: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))  # (C, 4, 4)
    # The first ids a frontend continuing this map may use (a restarted frontend): past every keyframe
    # and frontend point id the backend knows, mapped, culled, fused away or waiting in its inbox.
    next_keyframe_id: int = 0
    next_frontend_point_id: int = 0


@dataclass(frozen=True)
class LoopMessage:
    """A loop candidate that reached verification (backend/loop): accepted, or rejected with a reason."""

    keyframe_id: int
    stamp_ns: int
    loop_keyframe_id: int
    loop_stamp_ns: int
    accepted: bool
    reason: str  # why it was rejected; "" when accepted
    T_world_cur_before: np.ndarray  # (4, 4) the current keyframe's pose before any correction
    T_world_loop: np.ndarray  # (4, 4) the loop keyframe's pose
    # The verified transform, for an accepted loop and for one refused after verification (drift
    # budget, pose graph); identity with 0 inliers for a candidate that failed verification.
    T_cur_loop: np.ndarray = field(default_factory=lambda: np.eye(4))  # (4, 4) rigid part: loop camera -> current camera
    scale: float = 1.0  # the transform's scale (1 for stereo/RGB-D)
    inliers: int = 0
    T_world_cur_after: np.ndarray = field(default_factory=lambda: np.eye(4))  # (4, 4) after the correction


@dataclass(frozen=True)
class MapSnapshotMessage:
    """The backend's map (the backend/map reply): keyframe poses and P point positions."""

    keyframes: KeyframeTrajectoryMessage
    point_ids: np.ndarray  # (P,) int64
    p_world: np.ndarray  # (P, 3) metres, world frame


def _pack(array: np.ndarray, dtype: str, shape_tail: tuple[int, ...], name: str) -> bytes:
    a = np.asarray(array)
    if a.shape[1:] != shape_tail:
        raise MessageError(f"{name} must have shape (N, {', '.join(map(str, shape_tail))}), got {a.shape}")
    return np.ascontiguousarray(a, dtype=dtype).tobytes()


def _unpack(data: bytes, dtype: str, shape: tuple[int, ...], name: str) -> np.ndarray:
    dt = np.dtype(dtype)
    expected = int(np.prod(shape)) * dt.itemsize
    if len(data) != expected:
        raise MessageError(f"field {name}: expected {expected} bytes for {dt} {shape}, got {len(data)}; sender and receiver disagree")
    return np.frombuffer(data, dtype=dt).reshape(shape)


def array_field(message: Message, name: str) -> np.ndarray:
    """The array that bytes field ``name`` of ``message`` holds, shaped (rows, *row shape) with the
    element type of ARRAY_FIELDS; the raw bytes as uint8 for a field not listed there or whose
    length is not a whole number of rows."""
    data = bytes(getattr(message, name))
    dtype, row_shape = ARRAY_FIELDS.get(message.DESCRIPTOR.full_name, {}).get(name, ("u1", ()))
    row_bytes = np.dtype(dtype).itemsize * int(np.prod(row_shape))
    if len(data) % row_bytes:
        dtype, row_shape = "u1", ()
    return np.frombuffer(data, dtype=dtype).reshape((-1, *row_shape))


def _parse(cls: type[Message], data: bytes) -> Message:
    msg = cls()
    try:
        msg.ParseFromString(bytes(data))
    except DecodeError as exc:
        raise MessageError(f"cannot decode {len(data)} bytes as {cls.DESCRIPTOR.full_name}: {exc}") from exc
    return msg


def _calibration_to_pb(calibration: PinholeCalibration, out: pb.Calibration) -> None:
    out.fx, out.fy, out.cx, out.cy = calibration.fx, calibration.fy, calibration.cx, calibration.cy
    out.width, out.height = calibration.width, calibration.height
    if calibration.baseline_m is not None:
        out.baseline_m = calibration.baseline_m


def _calibration_from_pb(msg: pb.Calibration, where: str = "message") -> PinholeCalibration:
    baseline = msg.baseline_m if msg.HasField("baseline_m") else None
    try:
        return PinholeCalibration(msg.fx, msg.fy, msg.cx, msg.cy, msg.width, msg.height, baseline)
    except CalibrationError as exc:
        raise MessageError(f"{where}: {exc}") from exc


def _sensor_from_pb(value: int, where: str) -> SensorKind:
    for name, code in _SENSORS.items():
        if code == value:
            return name  # type: ignore[return-value]
    raise MessageError(f"{where}: sensor kind {value} is not mono, stereo or rgbd")


def _transform_to_pb(T: np.ndarray, out: pb.RigidTransform) -> None:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise MessageError(f"a pose must be a 4x4 transform, got shape {T.shape}")
    out.tx, out.ty, out.tz = (float(v) for v in T[:3, 3])
    out.qw, out.qx, out.qy, out.qz = (float(v) for v in R_to_quat_wxyz(T[:3, :3]))


def _transform_from_pb(msg: pb.RigidTransform) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = quat_wxyz_to_R(np.array([msg.qw, msg.qx, msg.qy, msg.qz]))
    T[:3, 3] = (msg.tx, msg.ty, msg.tz)
    return T


def png_bytes(image: np.ndarray, compression: int = 1) -> bytes:
    """A lossless PNG of a uint8 grey image at zlib level ``compression`` (0-9).

    Run-length deflate: on synthetic, KITTI and EuRoC frames it is as fast as Huffman-only and 1-4%
    smaller, and 10-20% smaller and faster than the default strategy (natural images have few long
    repeats for LZ77 to find). Every row takes PNG's Sub filter (each pixel less its left
    neighbour) rather than libpng's choice per row among all five, which tries each: 2.2-2.5x
    faster on KITTI and EuRoC frames for 5% more bytes, 1.6x on the synthetic scenes for 13% more
    (benchmarks/README.md, "Footprint of a run"). An OpenCV without ``IMWRITE_PNG_FILTER`` chooses per row.
    """
    params = [cv2.IMWRITE_PNG_COMPRESSION, compression, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
    params += _PNG_SUB_FILTER
    ok, data = cv2.imencode(".png", np.ascontiguousarray(image), params)
    if not ok:
        raise MessageError(f"OpenCV could not encode a {image.dtype} {image.shape} image as PNG")
    return data.tobytes()


_PNG_SUB_FILTER = (cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB) if hasattr(cv2, "IMWRITE_PNG_FILTER") else ()


def _encode_image(image: np.ndarray, encoding: ImageEncodingName, png_compression: int) -> bytes:
    return png_bytes(image, png_compression) if encoding == "png" else image.tobytes()


def _decode_image(data: bytes, encoding: int, shape: tuple[int, int], name: str) -> np.ndarray:
    if encoding == pb.IMAGE_ENCODING_RAW:
        return _unpack(data, "u1", shape, name)
    if encoding == pb.IMAGE_ENCODING_PNG_APART:
        raise MessageError(
            f"{name}: the image is stored apart from the message, on a recording's camera channels; "
            "read the recording with zenslam.service.mcap_io, which puts the images back"
        )
    if encoding != pb.IMAGE_ENCODING_PNG:
        raise MessageError(f"{name}: unknown image encoding {encoding}; the sender's zenslam is newer than this one")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint8 or image.shape != shape:
        got = "undecodable bytes" if image is None else f"{image.dtype} {image.shape}"
        raise MessageError(f"{name}: the PNG holds {got}, expected uint8 {shape}; the message is corrupt")
    image.flags.writeable = False  # like the raw encoding's views on the received bytes
    return image


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
    msg.sensor = _SENSORS[sensor]
    _calibration_to_pb(calibration, msg.calibration)
    msg.image_encoding = _IMAGE_ENCODINGS[image_encoding]
    msg.left = _encode_image(left, image_encoding, png_compression)
    if frame.right is not None:
        right = np.asarray(frame.right)
        if right.shape != left.shape or right.dtype != np.uint8:
            raise MessageError(f"frame {frame.index}: right image {right.dtype} {right.shape} must match left uint8 {left.shape}")
        msg.right = _encode_image(right, image_encoding, png_compression)
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
    msg = _parse(pb.SensorFrame, data)
    if msg.end_of_stream or msg.image_encoding == pb.IMAGE_ENCODING_PNG:
        return bytes(data)
    shape, where = (msg.height, msg.width), f"sensor frame {msg.index}"
    msg.left = png_bytes(_decode_image(msg.left, msg.image_encoding, shape, f"{where} left"), png_compression)
    if msg.right:
        msg.right = png_bytes(_decode_image(msg.right, msg.image_encoding, shape, f"{where} right"), png_compression)
    msg.image_encoding = pb.IMAGE_ENCODING_PNG
    return msg.SerializeToString()


def sensor_frame_images_apart(data: bytes, png_compression: int = 1) -> tuple[bytes, list[bytes]]:
    """The sensor/frame message ``data`` split for a recording that stores each image once:
    (the message without its images, IMAGE_ENCODING_PNG_APART; [left PNG, and right PNG if any]).

    Images already in PNG are kept as they are; an end of stream comes back unchanged with no images.
    ``sensor_frame_with_images`` puts them back.
    """
    msg = _parse(pb.SensorFrame, sensor_frame_as_png(data, png_compression))
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
    msg = _parse(pb.SensorFrame, data)
    if msg.end_of_stream or msg.image_encoding != pb.IMAGE_ENCODING_PNG_APART:
        return bytes(data)
    msg.image_encoding = pb.IMAGE_ENCODING_PNG
    msg.left = left_png
    if right_png is not None:
        msg.right = right_png
    return msg.SerializeToString()


def sensor_frame_images_are_apart(data: bytes) -> bool:
    """True when the sensor/frame message ``data`` holds no images: a recording stores them apart."""
    msg = _parse(pb.SensorFrame, data)
    return not msg.end_of_stream and msg.image_encoding == pb.IMAGE_ENCODING_PNG_APART


def decode_sensor_frame(data: bytes) -> FrameMessage | EndOfStream:
    """Decode a sensor/frame message (images raw or PNG); depth comes back as float32 metres whatever its encoding."""
    msg = _parse(pb.SensorFrame, data)
    if msg.end_of_stream:
        return EndOfStream(msg.count)
    shape = (msg.height, msg.width)
    where = f"sensor frame {msg.index}"
    left = _decode_image(msg.left, msg.image_encoding, shape, f"{where} left")
    right = _decode_image(msg.right, msg.image_encoding, shape, f"{where} right") if msg.right else None
    depth = None
    if msg.depth_encoding == pb.DEPTH_ENCODING_FLOAT32_M:
        depth = _unpack(msg.depth, "<f4", shape, f"{where} depth")
    elif msg.depth_encoding == pb.DEPTH_ENCODING_UINT16_MM:
        depth = _unpack(msg.depth, "<u2", shape, f"{where} depth").astype(np.float32) / np.float32(1000.0)
    frame = SensorFrame(index=msg.index, stamp_ns=msg.stamp_ns, left=left, right=right, depth_m=depth)
    calibration, sensor = _calibration_from_pb(msg.calibration, where), _sensor_from_pb(msg.sensor, where)
    check_frame_values(msg.index, msg.stamp_ns, shape, calibration.width, calibration.height, sensor, right is not None, depth is not None)
    return FrameMessage(frame, calibration, sensor, msg.source_name)


_STREAMS = (SENSOR_FRAME, TRACKING_STATE, KEYFRAME, MAP_UPDATE)


def encode_end_of_stream(schema: str, count: int) -> bytes:
    """The end-of-stream message of the stream whose schema is one of SENSOR_FRAME, TRACKING_STATE,
    KEYFRAME or MAP_UPDATE."""
    if schema not in _STREAMS:
        raise MessageError(f"streams of {schema!r} have no end-of-stream message; use one of {list(_STREAMS)}")
    return MESSAGE_CLASSES[schema](end_of_stream=True, count=count).SerializeToString()


def encode_tracking_state(state: TrackingStateMessage) -> bytes:
    """Encode a frontend/state message."""
    msg = pb.TrackingState(
        index=state.index,
        stamp_ns=state.stamp_ns,
        state=_TRACKING[state.state],
        lost_reason=state.lost_reason or "",
        n_tracked=state.n_tracked,
        has_pose=state.has_pose,
        keyframe_id=state.keyframe_id,
        relocalised=state.relocalised,
    )
    for name, ms in state.timings_ms.items():
        msg.timings_ms[name] = float(ms)
    if state.reference_keyframe_id >= 0 and state.T_reference_cam is not None:
        msg.reference_keyframe_id = state.reference_keyframe_id
        _transform_to_pb(state.T_reference_cam, msg.T_reference_cam)
    return msg.SerializeToString()


def decode_tracking_state(data: bytes) -> TrackingStateMessage | EndOfStream:
    """Decode a frontend/state message."""
    msg = _parse(pb.TrackingState, data)
    if msg.end_of_stream:
        return EndOfStream(msg.count)
    names = {code: name for name, code in _TRACKING.items()}
    if msg.state not in names:
        raise MessageError(f"tracking state of frame {msg.index}: unknown state code {msg.state}")
    return TrackingStateMessage(
        index=msg.index,
        stamp_ns=msg.stamp_ns,
        state=names[msg.state],  # type: ignore[arg-type]
        lost_reason=msg.lost_reason or None,
        n_tracked=msg.n_tracked,
        timings_ms={k: msg.timings_ms[k] for k in sorted(msg.timings_ms)},
        has_pose=msg.has_pose,
        keyframe_id=msg.keyframe_id,
        # Presence of the transform marks a reference: id 0 is a keyframe, not "unset".
        reference_keyframe_id=msg.reference_keyframe_id if msg.HasField("T_reference_cam") else -1,
        T_reference_cam=_transform_from_pb(msg.T_reference_cam) if msg.HasField("T_reference_cam") else None,
        relocalised=msg.relocalised,
    )


def encode_keyframe(kf: KeyframeMessage) -> bytes:
    """Encode a frontend/keyframe message; array shapes must agree with the keypoint count."""
    n = len(kf.keypoints_px)
    m = len(kf.new_point_ids)
    msg = pb.Keyframe(id=kf.id, stamp_ns=kf.stamp_ns, frame_index=kf.frame_index, num_keypoints=n, num_new_points=m)
    _transform_to_pb(kf.T_world_cam, msg.T_world_cam)
    _calibration_to_pb(kf.calibration, msg.calibration)
    msg.sensor = _SENSORS[kf.sensor]
    per_keypoint = {
        "levels": (kf.levels, "<i2", ()),
        "angles_deg": (kf.angles_deg, "<f4", ()),
        "right_u": (kf.right_u, "<f4", ()),
        "depth_m": (kf.depth_m, "<f4", ()),
        "descriptors": (kf.descriptors, "u1", (32,)),
        "map_point_ids": (kf.map_point_ids, "<i8", ()),
    }
    msg.keypoints_px = _pack(kf.keypoints_px, "<f4", (2,), f"keyframe {kf.id} keypoints_px")
    for name, (array, dtype, tail) in per_keypoint.items():
        if len(array) != n:
            raise MessageError(f"keyframe {kf.id}: {name} has {len(array)} entries for {n} keypoints")
        setattr(msg, name, _pack(array, dtype, tail, f"keyframe {kf.id} {name}"))
    if len(kf.new_points_world) != m:
        raise MessageError(f"keyframe {kf.id}: {len(kf.new_points_world)} new point positions for {m} new point ids")
    msg.new_point_ids = _pack(kf.new_point_ids, "<i8", (), f"keyframe {kf.id} new_point_ids")
    msg.new_points_world = _pack(kf.new_points_world, "<f8", (3,), f"keyframe {kf.id} new_points_world")
    msg.scale_factors = _pack(kf.scale_factors, "<f8", (), f"keyframe {kf.id} scale_factors")
    return msg.SerializeToString()


def decode_keyframe(data: bytes) -> KeyframeMessage | EndOfStream:
    """Decode a frontend/keyframe message."""
    msg = _parse(pb.Keyframe, data)
    if msg.end_of_stream:
        return EndOfStream(msg.count)
    n, m, where = msg.num_keypoints, msg.num_new_points, f"keyframe {msg.id}"
    keyframe = KeyframeMessage(
        id=msg.id,
        stamp_ns=msg.stamp_ns,
        frame_index=msg.frame_index,
        T_world_cam=_transform_from_pb(msg.T_world_cam),
        calibration=_calibration_from_pb(msg.calibration, where),
        sensor=_sensor_from_pb(msg.sensor, where),
        keypoints_px=_unpack(msg.keypoints_px, "<f4", (n, 2), f"{where} keypoints_px"),
        levels=_unpack(msg.levels, "<i2", (n,), f"{where} levels"),
        angles_deg=_unpack(msg.angles_deg, "<f4", (n,), f"{where} angles_deg"),
        right_u=_unpack(msg.right_u, "<f4", (n,), f"{where} right_u"),
        depth_m=_unpack(msg.depth_m, "<f4", (n,), f"{where} depth_m"),
        descriptors=_unpack(msg.descriptors, "u1", (n, 32), f"{where} descriptors"),
        map_point_ids=_unpack(msg.map_point_ids, "<i8", (n,), f"{where} map_point_ids"),
        scale_factors=_unpack(msg.scale_factors, "<f8", (len(msg.scale_factors) // 8,), f"{where} scale_factors"),
        new_point_ids=_unpack(msg.new_point_ids, "<i8", (m,), f"{where} new_point_ids"),
        new_points_world=_unpack(msg.new_points_world, "<f8", (m, 3), f"{where} new_points_world"),
    )
    k = keyframe
    check_keyframe_values(
        k.id, k.T_world_cam, k.calibration.width, k.calibration.height, k.keypoints_px, k.levels, k.angles_deg,
        k.right_u, k.depth_m, k.map_point_ids, k.scale_factors, k.new_point_ids, k.new_points_world,
    )
    return keyframe


_MAP_UPDATE_KIND_TO_PB = {"keyframe": pb.MAP_UPDATE_KIND_KEYFRAME, "correction": pb.MAP_UPDATE_KIND_CORRECTION}
# Recordings made before update kinds existed carry none: each of their updates answered a keyframe.
_MAP_UPDATE_KIND_FROM_PB = {pb.MAP_UPDATE_KIND_UNSPECIFIED: "keyframe", **{v: k for k, v in _MAP_UPDATE_KIND_TO_PB.items()}}


def encode_map_update(update: MapUpdate) -> bytes:
    """Encode a backend/map_update message."""
    msg = pb.MapUpdate(
        keyframe_id=update.keyframe_id, stamp_ns=update.stamp_ns, num_points=len(update.point_ids),
        kind=_MAP_UPDATE_KIND_TO_PB[update.kind], corrections_following=update.corrections_following,
        corrections_after_next_frame=update.corrections_after_next_frame,
    )
    for kf in update.keyframes:
        correction = msg.keyframes.add(id=kf.id, num_keypoints=len(kf.map_point_ids))
        _transform_to_pb(kf.T_world_cam, correction.T_world_cam)
        correction.map_point_ids = _pack(kf.map_point_ids, "<i8", (), f"map update keyframe {kf.id} map_point_ids")
    where = f"map update of keyframe {update.keyframe_id}"
    msg.point_ids = _pack(update.point_ids, "<i8", (), f"{where} point_ids")
    msg.p_world = _pack(update.p_world, "<f8", (3,), f"{where} p_world")
    msg.descriptors = _pack(update.descriptors, "u1", (32,), f"{where} descriptors")
    msg.normals_f32 = _pack(update.normals, "<f4", (3,), f"{where} normals")
    msg.min_distance_m_f32 = _pack(update.min_distance_m, "<f4", (), f"{where} min_distance_m")
    msg.max_distance_m_f32 = _pack(update.max_distance_m, "<f4", (), f"{where} max_distance_m")
    msg.removed_point_ids = _pack(update.removed_point_ids, "<i8", (), f"{where} removed_point_ids")
    msg.removed_keyframe_ids = _pack(update.removed_keyframe_ids, "<i8", (), f"{where} removed_keyframe_ids")
    return msg.SerializeToString()


def decode_map_update(data: bytes) -> MapUpdate | EndOfStream:
    """Decode a backend/map_update message."""
    msg = _parse(pb.MapUpdate, data)
    if msg.end_of_stream:
        return EndOfStream(msg.count)
    p, where = msg.num_points, f"map update of keyframe {msg.keyframe_id}"
    keyframes = tuple(
        KeyframeCorrection(
            id=kf.id,
            T_world_cam=_transform_from_pb(kf.T_world_cam),
            map_point_ids=_unpack(kf.map_point_ids, "<i8", (kf.num_keypoints,), f"{where} keyframe {kf.id} map_point_ids"),
        )
        for kf in msg.keyframes
    )
    if msg.kind not in _MAP_UPDATE_KIND_FROM_PB:
        raise MessageError(f"{where}: update kind {msg.kind} is unknown; the sender's zenslam is newer than this one")
    update = MapUpdate(
        kind=_MAP_UPDATE_KIND_FROM_PB[msg.kind],
        corrections_following=msg.corrections_following,
        corrections_after_next_frame=msg.corrections_after_next_frame,
        keyframe_id=msg.keyframe_id,
        stamp_ns=msg.stamp_ns,
        keyframes=keyframes,
        point_ids=_unpack(msg.point_ids, "<i8", (p,), f"{where} point_ids"),
        p_world=_unpack(msg.p_world, "<f8", (p, 3), f"{where} p_world"),
        descriptors=_unpack(msg.descriptors, "u1", (p, 32), f"{where} descriptors"),
        normals=_unpack_float(msg, "normals", (p, 3), where),
        min_distance_m=_unpack_float(msg, "min_distance_m", (p,), where),
        max_distance_m=_unpack_float(msg, "max_distance_m", (p,), where),
        removed_point_ids=_unpack(msg.removed_point_ids, "<i8", (len(msg.removed_point_ids) // 8,), f"{where} removed_point_ids"),
        removed_keyframe_ids=_unpack(
            msg.removed_keyframe_ids, "<i8", (len(msg.removed_keyframe_ids) // 8,), f"{where} removed_keyframe_ids"
        ),
    )
    u = update
    check_map_update_values(
        u.keyframe_id, [(kf.id, kf.T_world_cam, kf.map_point_ids) for kf in u.keyframes], u.point_ids, u.p_world,
        u.normals, u.min_distance_m, u.max_distance_m, u.removed_point_ids, u.removed_keyframe_ids,
    )
    return update


def _unpack_float(msg: pb.MapUpdate, name: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """Float64 values of map-update field ``name``: from its float32 field, or from the float64 one of
    recordings made before the float32 fields existed."""
    narrow = getattr(msg, f"{name}_f32")
    if narrow or not getattr(msg, name):
        return _unpack(narrow, "<f4", shape, f"{where} {name}").astype(np.float64)
    return _unpack(getattr(msg, name), "<f8", shape, f"{where} {name}")


def encode_loop(loop: LoopMessage) -> bytes:
    """Encode a backend/loop message."""
    msg = pb.Loop(
        keyframe_id=loop.keyframe_id, stamp_ns=loop.stamp_ns, loop_keyframe_id=loop.loop_keyframe_id,
        loop_stamp_ns=loop.loop_stamp_ns, accepted=loop.accepted, reason=loop.reason, scale=loop.scale, inliers=loop.inliers,
    )
    _transform_to_pb(loop.T_world_cur_before, msg.T_world_cur_before)
    _transform_to_pb(loop.T_world_loop, msg.T_world_loop)
    if loop.accepted or loop.inliers > 0:
        _transform_to_pb(loop.T_cur_loop, msg.T_cur_loop)
    if loop.accepted:
        _transform_to_pb(loop.T_world_cur_after, msg.T_world_cur_after)
    return msg.SerializeToString()


def decode_loop(data: bytes) -> LoopMessage:
    """Decode a backend/loop message (an unaccepted loop's pose after the correction is the identity,
    and so is the transform of one that failed verification)."""
    msg = _parse(pb.Loop, data)
    accepted = bool(msg.accepted)
    verified = accepted or msg.inliers > 0
    return LoopMessage(
        keyframe_id=msg.keyframe_id, stamp_ns=msg.stamp_ns, loop_keyframe_id=msg.loop_keyframe_id,
        loop_stamp_ns=msg.loop_stamp_ns, accepted=accepted, reason=msg.reason,
        T_world_cur_before=_transform_from_pb(msg.T_world_cur_before), T_world_loop=_transform_from_pb(msg.T_world_loop),
        T_cur_loop=_transform_from_pb(msg.T_cur_loop) if verified else np.eye(4),
        scale=msg.scale if verified else 1.0, inliers=msg.inliers,
        T_world_cur_after=_transform_from_pb(msg.T_world_cur_after) if accepted else np.eye(4),
    )


def encode_pose_in_frame(pose: StampedPose) -> bytes:
    """Encode a pose as foxglove.PoseInFrame (what Foxglove and rerun's MCAP reader draw)."""
    msg = PoseInFrame(frame_id=pose.frame_id)
    seconds, nanos = divmod(int(pose.stamp_ns), _NS_PER_S)
    msg.timestamp.seconds, msg.timestamp.nanos = seconds, nanos
    T = np.asarray(pose.T_world_cam, dtype=float)
    if T.shape != (4, 4):
        raise MessageError(f"a pose must be a 4x4 transform, got shape {T.shape}")
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in T[:3, 3])
    w, x, y, z = R_to_quat_wxyz(T[:3, :3])
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = float(x), float(y), float(z), float(w)  # foxglove orders quaternions x, y, z, w
    return msg.SerializeToString()


def decode_pose_in_frame(data: bytes) -> StampedPose:
    """Decode a foxglove.PoseInFrame message."""
    msg = _parse(PoseInFrame, data)
    o, p = msg.pose.orientation, msg.pose.position
    T = np.eye(4)
    T[:3, :3] = quat_wxyz_to_R(np.array([o.w, o.x, o.y, o.z]))
    T[:3, 3] = (p.x, p.y, p.z)
    stamp_ns = msg.timestamp.seconds * _NS_PER_S + msg.timestamp.nanos
    return StampedPose(stamp_ns, T, msg.frame_id)


def encode_stage_status(status: StageStatusMessage) -> bytes:
    """Encode a <stage>/status message."""
    msg = pb.StageStatus(
        stage=status.stage,
        state=_STAGE[status.state],
        processed=status.processed,
        step_ms=status.step_ms,
        queue_depth=status.queue_depth,
        dropped=status.dropped,
        detail=status.detail,
    )
    for name, ms in status.timings_ms.items():
        msg.timings_ms[name] = float(ms)
    for reason, count in status.skipped.items():
        msg.skipped[reason] = int(count)
    return msg.SerializeToString()


def decode_stage_status(data: bytes) -> StageStatusMessage:
    """Decode a <stage>/status message."""
    msg = _parse(pb.StageStatus, data)
    names = {code: name for name, code in _STAGE.items()}
    if msg.state not in names:
        raise MessageError(f"status of stage {msg.stage!r}: unknown state code {msg.state}")
    return StageStatusMessage(
        stage=msg.stage,
        state=names[msg.state],  # type: ignore[arg-type]
        processed=msg.processed,
        step_ms=msg.step_ms,
        queue_depth=msg.queue_depth,
        dropped=msg.dropped,
        detail=msg.detail,
        timings_ms={k: msg.timings_ms[k] for k in sorted(msg.timings_ms)},
        skipped={k: int(msg.skipped[k]) for k in sorted(msg.skipped)},
    )


def _trajectory_to_pb(trajectory: KeyframeTrajectoryMessage, out: pb.KeyframeTrajectory) -> None:
    k = len(trajectory.keyframe_ids)
    if len(trajectory.stamps_ns) != k or np.shape(trajectory.T_world_cam) != (k, 4, 4):
        raise MessageError(
            f"keyframe trajectory: {k} ids, {len(trajectory.stamps_ns)} stamps and poses of shape "
            f"{np.shape(trajectory.T_world_cam)} do not agree (expected ({k}, 4, 4))"
        )
    out.keyframes_processed, out.finished, out.num_keyframes = trajectory.keyframes_processed, trajectory.finished, k
    out.next_keyframe_id, out.next_frontend_point_id = trajectory.next_keyframe_id, trajectory.next_frontend_point_id
    out.keyframe_ids = _pack(trajectory.keyframe_ids, "<i8", (), "keyframe trajectory keyframe_ids")
    out.stamps_ns = _pack(trajectory.stamps_ns, "<i8", (), "keyframe trajectory stamps_ns")
    out.T_world_cam = _pack(trajectory.T_world_cam, "<f8", (4, 4), "keyframe trajectory T_world_cam")
    c = len(trajectory.culled_keyframe_ids)
    if len(trajectory.culled_stamps_ns) != c or np.shape(trajectory.culled_T_world_cam) != (c, 4, 4):
        raise MessageError(
            f"keyframe trajectory: {c} culled ids, {len(trajectory.culled_stamps_ns)} stamps and poses of shape "
            f"{np.shape(trajectory.culled_T_world_cam)} do not agree (expected ({c}, 4, 4))"
        )
    if c:
        out.num_culled = c
        out.culled_keyframe_ids = _pack(trajectory.culled_keyframe_ids, "<i8", (), "keyframe trajectory culled_keyframe_ids")
        out.culled_stamps_ns = _pack(trajectory.culled_stamps_ns, "<i8", (), "keyframe trajectory culled_stamps_ns")
        out.culled_T_world_cam = _pack(trajectory.culled_T_world_cam, "<f8", (4, 4), "keyframe trajectory culled_T_world_cam")


def _trajectory_from_pb(msg: pb.KeyframeTrajectory) -> KeyframeTrajectoryMessage:
    k, c = msg.num_keyframes, msg.num_culled
    return KeyframeTrajectoryMessage(
        keyframe_ids=_unpack(msg.keyframe_ids, "<i8", (k,), "keyframe trajectory keyframe_ids"),
        stamps_ns=_unpack(msg.stamps_ns, "<i8", (k,), "keyframe trajectory stamps_ns"),
        T_world_cam=_unpack(msg.T_world_cam, "<f8", (k, 4, 4), "keyframe trajectory T_world_cam"),
        keyframes_processed=msg.keyframes_processed,
        finished=msg.finished,
        culled_keyframe_ids=_unpack(msg.culled_keyframe_ids, "<i8", (c,), "keyframe trajectory culled_keyframe_ids"),
        culled_stamps_ns=_unpack(msg.culled_stamps_ns, "<i8", (c,), "keyframe trajectory culled_stamps_ns"),
        culled_T_world_cam=_unpack(msg.culled_T_world_cam, "<f8", (c, 4, 4), "keyframe trajectory culled_T_world_cam"),
        next_keyframe_id=msg.next_keyframe_id,
        next_frontend_point_id=msg.next_frontend_point_id,
    )


def encode_keyframe_trajectory(trajectory: KeyframeTrajectoryMessage) -> bytes:
    """Encode a backend/trajectory reply."""
    msg = pb.KeyframeTrajectory()
    _trajectory_to_pb(trajectory, msg)
    return msg.SerializeToString()


def decode_keyframe_trajectory(data: bytes) -> KeyframeTrajectoryMessage:
    """Decode a backend/trajectory reply."""
    return _trajectory_from_pb(_parse(pb.KeyframeTrajectory, data))


def encode_map_snapshot(snapshot: MapSnapshotMessage) -> bytes:
    """Encode a backend/map reply; point ids and positions must agree in length."""
    p = len(snapshot.point_ids)
    if len(snapshot.p_world) != p:
        raise MessageError(f"map snapshot: {len(snapshot.p_world)} point positions for {p} point ids")
    msg = pb.MapSnapshot(num_points=p)
    _trajectory_to_pb(snapshot.keyframes, msg.keyframes)
    msg.point_ids = _pack(snapshot.point_ids, "<i8", (), "map snapshot point_ids")
    msg.p_world = _pack(snapshot.p_world, "<f8", (3,), "map snapshot p_world")
    return msg.SerializeToString()


def decode_map_snapshot(data: bytes) -> MapSnapshotMessage:
    """Decode a backend/map reply."""
    msg = _parse(pb.MapSnapshot, data)
    p = msg.num_points
    return MapSnapshotMessage(
        keyframes=_trajectory_from_pb(msg.keyframes),
        point_ids=_unpack(msg.point_ids, "<i8", (p,), "map snapshot point_ids"),
        p_world=_unpack(msg.p_world, "<f8", (p, 3), "map snapshot p_world"),
    )


def encode_relocalisation_query(query: RelocalisationQuery) -> bytes:
    """Encode a backend/relocalisation query."""
    msg = pb.RelocalisationQuery(
        stamp_ns=query.stamp_ns, num_words=len(query.word_ids),
        max_candidates=query.max_candidates, max_neighbours=query.max_neighbours,
    )
    msg.word_ids = _pack(query.word_ids, "<i8", (), "relocalisation query word_ids")
    msg.weights = _pack(query.weights, "<f8", (), "relocalisation query weights")
    if query.window_keyframe_id >= 0:
        msg.window_keyframe_id = query.window_keyframe_id
    return msg.SerializeToString()


def decode_relocalisation_query(data: bytes) -> RelocalisationQuery:
    """Decode a backend/relocalisation query."""
    msg = _parse(pb.RelocalisationQuery, data)
    w = msg.num_words
    return RelocalisationQuery(
        stamp_ns=msg.stamp_ns,
        word_ids=_unpack(msg.word_ids, "<i8", (w,), "relocalisation query word_ids"),
        weights=_unpack(msg.weights, "<f8", (w,), "relocalisation query weights"),
        max_candidates=msg.max_candidates,
        max_neighbours=msg.max_neighbours,
        window_keyframe_id=msg.window_keyframe_id if msg.HasField("window_keyframe_id") else -1,
    )


_MAP_KEYFRAME_ARRAYS: dict[str, tuple[str, tuple[int, ...]]] = {
    "levels": ("<i2", ()), "angles_deg": ("<f4", ()), "right_u": ("<f4", ()), "depth_m": ("<f4", ()),
    "descriptors": ("u1", (32,)), "map_point_ids": ("<i8", ()),
}  # fmt: skip
_MAP_POINT_ARRAYS: dict[str, tuple[str, str, tuple[int, ...]]] = {  # message field: (MapPoints field, dtype, row)
    "point_ids": ("ids", "<i8", ()), "p_world": ("p_world", "<f8", (3,)), "descriptors": ("descriptors", "u1", (32,)),
    "normals": ("normals", "<f8", (3,)), "min_distance_m": ("min_distance_m", "<f8", ()),
    "max_distance_m": ("max_distance_m", "<f8", ()),
}  # fmt: skip


def encode_relocalisation_candidates(reply: RelocalisationCandidates) -> bytes:
    """Encode a backend/relocalisation reply; every keyframe's arrays must agree with its keypoint count."""
    msg = pb.RelocalisationCandidates(
        stamp_ns=reply.stamp_ns, keyframes_processed=reply.keyframes_processed, num_points=len(reply.points.ids)
    )
    for candidate in reply.candidates:
        out = msg.candidates.add(keyframe_id=candidate.keyframe_id, score=candidate.score)
        out.neighbour_ids = _pack(candidate.neighbour_ids, "<i8", (), f"relocalisation candidate {candidate.keyframe_id} neighbour_ids")
    for kf in reply.keyframes:
        n, where = len(kf.keypoints_px), f"relocalisation keyframe {kf.id}"
        out = msg.keyframes.add(id=kf.id, stamp_ns=kf.stamp_ns, num_keypoints=n)
        _transform_to_pb(kf.T_world_cam, out.T_world_cam)
        out.keypoints_px = _pack(kf.keypoints_px, "<f4", (2,), f"{where} keypoints_px")
        for name, (dtype, tail) in _MAP_KEYFRAME_ARRAYS.items():
            array = getattr(kf, name)
            if len(array) != n:
                raise MessageError(f"{where}: {name} has {len(array)} entries for {n} keypoints")
            setattr(out, name, _pack(array, dtype, tail, f"{where} {name}"))
        out.scale_factors = _pack(kf.scale_factors, "<f8", (), f"{where} scale_factors")
    for name, (attr, dtype, tail) in _MAP_POINT_ARRAYS.items():
        setattr(msg, name, _pack(getattr(reply.points, attr), dtype, tail, f"relocalisation reply {name}"))
    return msg.SerializeToString()


def decode_relocalisation_candidates(data: bytes) -> RelocalisationCandidates:
    """Decode a backend/relocalisation reply."""
    msg = _parse(pb.RelocalisationCandidates, data)
    candidates = tuple(
        RelocalisationCandidate(
            keyframe_id=c.keyframe_id,
            score=c.score,
            neighbour_ids=_unpack(c.neighbour_ids, "<i8", (len(c.neighbour_ids) // 8,), f"relocalisation candidate {c.keyframe_id} neighbour_ids"),
        )
        for c in msg.candidates
    )
    keyframes = []
    for kf in msg.keyframes:
        n, where = kf.num_keypoints, f"relocalisation keyframe {kf.id}"
        arrays = {name: _unpack(getattr(kf, name), dtype, (n, *tail), f"{where} {name}") for name, (dtype, tail) in _MAP_KEYFRAME_ARRAYS.items()}
        keyframes.append(
            MapKeyframe(
                id=kf.id,
                stamp_ns=kf.stamp_ns,
                T_world_cam=_transform_from_pb(kf.T_world_cam),
                keypoints_px=_unpack(kf.keypoints_px, "<f4", (n, 2), f"{where} keypoints_px"),
                scale_factors=_unpack(kf.scale_factors, "<f8", (len(kf.scale_factors) // 8,), f"{where} scale_factors"),
                **arrays,
            )
        )
    p = msg.num_points
    points = MapPoints(**{
        attr: _unpack(getattr(msg, name), dtype, (p, *tail), f"relocalisation reply {name}")
        for name, (attr, dtype, tail) in _MAP_POINT_ARRAYS.items()
    })  # fmt: skip
    return RelocalisationCandidates(msg.stamp_ns, candidates, tuple(keyframes), points, msg.keyframes_processed)
