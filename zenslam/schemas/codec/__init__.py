"""The only encoder/decoder of zenslam bus messages: numpy arrays and dataclasses <-> protobuf bytes.

Arrays travel as raw little-endian ``bytes`` fields (see zenslam.proto for each field's dtype
and shape); decoding checks every length against the counts in the message, so a truncated or
mismatched message fails here with the field's name rather than deep inside a stage. Decoded
arrays are read-only views on the received bytes (PNG-encoded images: read-only decoded copies).

One module per message family, on shared packing helpers (``packing``): ``frames`` (and their
``images``), ``status`` (tracking states and stage status), ``keyframes``, ``map_updates``,
``loops``, ``poses``, ``trajectories`` (the trajectory and map replies), ``relocalisation``;
``message_types`` names every schema and array layout, ``end_of_stream`` ends a stream. Callers
use this package: ``from zenslam.schemas import codec``, then ``codec.encode_keyframe(...)``.
"""

from zenslam.errors import MessageError
from zenslam.schemas.codec.end_of_stream import EndOfStream, encode_end_of_stream
from zenslam.schemas.codec.frames import (
    DepthEncodingName,
    FrameMessage,
    decode_sensor_frame,
    encode_sensor_frame,
    sensor_frame_as_png,
    sensor_frame_images_apart,
    sensor_frame_images_are_apart,
    sensor_frame_with_images,
)
from zenslam.schemas.codec.images import ImageEncodingName, png_bytes
from zenslam.schemas.codec.keyframes import KeyframeMessage, decode_keyframe, encode_keyframe
from zenslam.schemas.codec.loops import LoopMessage, decode_loop, encode_loop
from zenslam.schemas.codec.map_updates import decode_map_update, encode_map_update
from zenslam.schemas.codec.message_types import (
    ARRAY_FIELDS,
    KEYFRAME,
    KEYFRAME_TRAJECTORY,
    LOOP,
    MAP_SNAPSHOT,
    MAP_UPDATE,
    MESSAGE_CLASSES,
    POSE_IN_FRAME,
    RELOCALISATION_CANDIDATES,
    RELOCALISATION_QUERY,
    SENSOR_FRAME,
    STAGE_STATUS,
    TRACKING_STATE,
    ArrayLayout,
    array_field,
)
from zenslam.schemas.codec.poses import StampedPose, decode_pose_in_frame, encode_pose_in_frame
from zenslam.schemas.codec.relocalisation import (
    decode_relocalisation_candidates,
    decode_relocalisation_query,
    encode_relocalisation_candidates,
    encode_relocalisation_query,
)
from zenslam.schemas.codec.status import (
    StageStateName,
    StageStatusMessage,
    TrackingStateMessage,
    TrackingStateName,
    decode_stage_status,
    decode_tracking_state,
    encode_stage_status,
    encode_tracking_state,
)
from zenslam.schemas.codec.trajectories import (
    KeyframeTrajectoryMessage,
    MapSnapshotMessage,
    decode_keyframe_trajectory,
    decode_map_snapshot,
    encode_keyframe_trajectory,
    encode_map_snapshot,
)

__all__ = [
    "ARRAY_FIELDS",
    "KEYFRAME",
    "KEYFRAME_TRAJECTORY",
    "LOOP",
    "MAP_SNAPSHOT",
    "MAP_UPDATE",
    "MESSAGE_CLASSES",
    "POSE_IN_FRAME",
    "RELOCALISATION_CANDIDATES",
    "RELOCALISATION_QUERY",
    "SENSOR_FRAME",
    "STAGE_STATUS",
    "TRACKING_STATE",
    "ArrayLayout",
    "DepthEncodingName",
    "EndOfStream",
    "FrameMessage",
    "ImageEncodingName",
    "KeyframeMessage",
    "KeyframeTrajectoryMessage",
    "LoopMessage",
    "MapSnapshotMessage",
    "MessageError",
    "StageStateName",
    "StageStatusMessage",
    "StampedPose",
    "TrackingStateMessage",
    "TrackingStateName",
    "array_field",
    "decode_keyframe",
    "decode_keyframe_trajectory",
    "decode_loop",
    "decode_map_snapshot",
    "decode_map_update",
    "decode_pose_in_frame",
    "decode_relocalisation_candidates",
    "decode_relocalisation_query",
    "decode_sensor_frame",
    "decode_stage_status",
    "decode_tracking_state",
    "encode_end_of_stream",
    "encode_keyframe",
    "encode_keyframe_trajectory",
    "encode_loop",
    "encode_map_snapshot",
    "encode_map_update",
    "encode_pose_in_frame",
    "encode_relocalisation_candidates",
    "encode_relocalisation_query",
    "encode_sensor_frame",
    "encode_stage_status",
    "encode_tracking_state",
    "png_bytes",
    "sensor_frame_as_png",
    "sensor_frame_images_apart",
    "sensor_frame_images_are_apart",
    "sensor_frame_with_images",
]
