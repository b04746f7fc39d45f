"""The bus's message types: their schema names, protobuf classes and the layout of every array field."""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from google.protobuf.message import Message

from zenslam.schemas import zenslam_pb2 as pb

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
