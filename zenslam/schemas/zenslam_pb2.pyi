from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class SensorKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SENSOR_KIND_UNSPECIFIED: _ClassVar[SensorKind]
    SENSOR_KIND_MONO: _ClassVar[SensorKind]
    SENSOR_KIND_STEREO: _ClassVar[SensorKind]
    SENSOR_KIND_RGBD: _ClassVar[SensorKind]

class DepthEncoding(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    DEPTH_ENCODING_NONE: _ClassVar[DepthEncoding]
    DEPTH_ENCODING_FLOAT32_M: _ClassVar[DepthEncoding]
    DEPTH_ENCODING_UINT16_MM: _ClassVar[DepthEncoding]

class ImageEncoding(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    IMAGE_ENCODING_RAW: _ClassVar[ImageEncoding]
    IMAGE_ENCODING_PNG: _ClassVar[ImageEncoding]
    IMAGE_ENCODING_PNG_APART: _ClassVar[ImageEncoding]

class TrackingStateKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    TRACKING_STATE_UNSPECIFIED: _ClassVar[TrackingStateKind]
    TRACKING_STATE_OK: _ClassVar[TrackingStateKind]
    TRACKING_STATE_LOST: _ClassVar[TrackingStateKind]
    TRACKING_STATE_INITIALIZING: _ClassVar[TrackingStateKind]

class MapUpdateKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    MAP_UPDATE_KIND_UNSPECIFIED: _ClassVar[MapUpdateKind]
    MAP_UPDATE_KIND_KEYFRAME: _ClassVar[MapUpdateKind]
    MAP_UPDATE_KIND_CORRECTION: _ClassVar[MapUpdateKind]

class StageState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    STAGE_STATE_UNSPECIFIED: _ClassVar[StageState]
    STAGE_STATE_STARTING: _ClassVar[StageState]
    STAGE_STATE_RUNNING: _ClassVar[StageState]
    STAGE_STATE_FINISHED: _ClassVar[StageState]
    STAGE_STATE_FAILED: _ClassVar[StageState]
SENSOR_KIND_UNSPECIFIED: SensorKind
SENSOR_KIND_MONO: SensorKind
SENSOR_KIND_STEREO: SensorKind
SENSOR_KIND_RGBD: SensorKind
DEPTH_ENCODING_NONE: DepthEncoding
DEPTH_ENCODING_FLOAT32_M: DepthEncoding
DEPTH_ENCODING_UINT16_MM: DepthEncoding
IMAGE_ENCODING_RAW: ImageEncoding
IMAGE_ENCODING_PNG: ImageEncoding
IMAGE_ENCODING_PNG_APART: ImageEncoding
TRACKING_STATE_UNSPECIFIED: TrackingStateKind
TRACKING_STATE_OK: TrackingStateKind
TRACKING_STATE_LOST: TrackingStateKind
TRACKING_STATE_INITIALIZING: TrackingStateKind
MAP_UPDATE_KIND_UNSPECIFIED: MapUpdateKind
MAP_UPDATE_KIND_KEYFRAME: MapUpdateKind
MAP_UPDATE_KIND_CORRECTION: MapUpdateKind
STAGE_STATE_UNSPECIFIED: StageState
STAGE_STATE_STARTING: StageState
STAGE_STATE_RUNNING: StageState
STAGE_STATE_FINISHED: StageState
STAGE_STATE_FAILED: StageState

class Calibration(_message.Message):
    __slots__ = ("fx", "fy", "cx", "cy", "width", "height", "baseline_m")
    FX_FIELD_NUMBER: _ClassVar[int]
    FY_FIELD_NUMBER: _ClassVar[int]
    CX_FIELD_NUMBER: _ClassVar[int]
    CY_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    BASELINE_M_FIELD_NUMBER: _ClassVar[int]
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    baseline_m: float
    def __init__(self, fx: _Optional[float] = ..., fy: _Optional[float] = ..., cx: _Optional[float] = ..., cy: _Optional[float] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., baseline_m: _Optional[float] = ...) -> None: ...

class RigidTransform(_message.Message):
    __slots__ = ("tx", "ty", "tz", "qw", "qx", "qy", "qz")
    TX_FIELD_NUMBER: _ClassVar[int]
    TY_FIELD_NUMBER: _ClassVar[int]
    TZ_FIELD_NUMBER: _ClassVar[int]
    QW_FIELD_NUMBER: _ClassVar[int]
    QX_FIELD_NUMBER: _ClassVar[int]
    QY_FIELD_NUMBER: _ClassVar[int]
    QZ_FIELD_NUMBER: _ClassVar[int]
    tx: float
    ty: float
    tz: float
    qw: float
    qx: float
    qy: float
    qz: float
    def __init__(self, tx: _Optional[float] = ..., ty: _Optional[float] = ..., tz: _Optional[float] = ..., qw: _Optional[float] = ..., qx: _Optional[float] = ..., qy: _Optional[float] = ..., qz: _Optional[float] = ...) -> None: ...

class SensorFrame(_message.Message):
    __slots__ = ("index", "stamp_ns", "width", "height", "sensor", "calibration", "left", "right", "depth_encoding", "depth", "source_name", "end_of_stream", "count", "image_encoding")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    SENSOR_FIELD_NUMBER: _ClassVar[int]
    CALIBRATION_FIELD_NUMBER: _ClassVar[int]
    LEFT_FIELD_NUMBER: _ClassVar[int]
    RIGHT_FIELD_NUMBER: _ClassVar[int]
    DEPTH_ENCODING_FIELD_NUMBER: _ClassVar[int]
    DEPTH_FIELD_NUMBER: _ClassVar[int]
    SOURCE_NAME_FIELD_NUMBER: _ClassVar[int]
    END_OF_STREAM_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    IMAGE_ENCODING_FIELD_NUMBER: _ClassVar[int]
    index: int
    stamp_ns: int
    width: int
    height: int
    sensor: SensorKind
    calibration: Calibration
    left: bytes
    right: bytes
    depth_encoding: DepthEncoding
    depth: bytes
    source_name: str
    end_of_stream: bool
    count: int
    image_encoding: ImageEncoding
    def __init__(self, index: _Optional[int] = ..., stamp_ns: _Optional[int] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., sensor: _Optional[_Union[SensorKind, str]] = ..., calibration: _Optional[_Union[Calibration, _Mapping]] = ..., left: _Optional[bytes] = ..., right: _Optional[bytes] = ..., depth_encoding: _Optional[_Union[DepthEncoding, str]] = ..., depth: _Optional[bytes] = ..., source_name: _Optional[str] = ..., end_of_stream: _Optional[bool] = ..., count: _Optional[int] = ..., image_encoding: _Optional[_Union[ImageEncoding, str]] = ...) -> None: ...

class TrackingState(_message.Message):
    __slots__ = ("index", "stamp_ns", "state", "lost_reason", "n_tracked", "timings_ms", "has_pose", "keyframe_id", "end_of_stream", "count", "reference_keyframe_id", "T_reference_cam", "relocalised")
    class TimingsMsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    INDEX_FIELD_NUMBER: _ClassVar[int]
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    LOST_REASON_FIELD_NUMBER: _ClassVar[int]
    N_TRACKED_FIELD_NUMBER: _ClassVar[int]
    TIMINGS_MS_FIELD_NUMBER: _ClassVar[int]
    HAS_POSE_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    END_OF_STREAM_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    REFERENCE_KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    T_REFERENCE_CAM_FIELD_NUMBER: _ClassVar[int]
    RELOCALISED_FIELD_NUMBER: _ClassVar[int]
    index: int
    stamp_ns: int
    state: TrackingStateKind
    lost_reason: str
    n_tracked: int
    timings_ms: _containers.ScalarMap[str, float]
    has_pose: bool
    keyframe_id: int
    end_of_stream: bool
    count: int
    reference_keyframe_id: int
    T_reference_cam: RigidTransform
    relocalised: bool
    def __init__(self, index: _Optional[int] = ..., stamp_ns: _Optional[int] = ..., state: _Optional[_Union[TrackingStateKind, str]] = ..., lost_reason: _Optional[str] = ..., n_tracked: _Optional[int] = ..., timings_ms: _Optional[_Mapping[str, float]] = ..., has_pose: _Optional[bool] = ..., keyframe_id: _Optional[int] = ..., end_of_stream: _Optional[bool] = ..., count: _Optional[int] = ..., reference_keyframe_id: _Optional[int] = ..., T_reference_cam: _Optional[_Union[RigidTransform, _Mapping]] = ..., relocalised: _Optional[bool] = ...) -> None: ...

class Keyframe(_message.Message):
    __slots__ = ("id", "stamp_ns", "frame_index", "T_world_cam", "calibration", "sensor", "num_keypoints", "keypoints_px", "levels", "angles_deg", "right_u", "depth_m", "descriptors", "map_point_ids", "scale_factors", "num_new_points", "new_point_ids", "new_points_world", "end_of_stream", "count")
    ID_FIELD_NUMBER: _ClassVar[int]
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    FRAME_INDEX_FIELD_NUMBER: _ClassVar[int]
    T_WORLD_CAM_FIELD_NUMBER: _ClassVar[int]
    CALIBRATION_FIELD_NUMBER: _ClassVar[int]
    SENSOR_FIELD_NUMBER: _ClassVar[int]
    NUM_KEYPOINTS_FIELD_NUMBER: _ClassVar[int]
    KEYPOINTS_PX_FIELD_NUMBER: _ClassVar[int]
    LEVELS_FIELD_NUMBER: _ClassVar[int]
    ANGLES_DEG_FIELD_NUMBER: _ClassVar[int]
    RIGHT_U_FIELD_NUMBER: _ClassVar[int]
    DEPTH_M_FIELD_NUMBER: _ClassVar[int]
    DESCRIPTORS_FIELD_NUMBER: _ClassVar[int]
    MAP_POINT_IDS_FIELD_NUMBER: _ClassVar[int]
    SCALE_FACTORS_FIELD_NUMBER: _ClassVar[int]
    NUM_NEW_POINTS_FIELD_NUMBER: _ClassVar[int]
    NEW_POINT_IDS_FIELD_NUMBER: _ClassVar[int]
    NEW_POINTS_WORLD_FIELD_NUMBER: _ClassVar[int]
    END_OF_STREAM_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    id: int
    stamp_ns: int
    frame_index: int
    T_world_cam: RigidTransform
    calibration: Calibration
    sensor: SensorKind
    num_keypoints: int
    keypoints_px: bytes
    levels: bytes
    angles_deg: bytes
    right_u: bytes
    depth_m: bytes
    descriptors: bytes
    map_point_ids: bytes
    scale_factors: bytes
    num_new_points: int
    new_point_ids: bytes
    new_points_world: bytes
    end_of_stream: bool
    count: int
    def __init__(self, id: _Optional[int] = ..., stamp_ns: _Optional[int] = ..., frame_index: _Optional[int] = ..., T_world_cam: _Optional[_Union[RigidTransform, _Mapping]] = ..., calibration: _Optional[_Union[Calibration, _Mapping]] = ..., sensor: _Optional[_Union[SensorKind, str]] = ..., num_keypoints: _Optional[int] = ..., keypoints_px: _Optional[bytes] = ..., levels: _Optional[bytes] = ..., angles_deg: _Optional[bytes] = ..., right_u: _Optional[bytes] = ..., depth_m: _Optional[bytes] = ..., descriptors: _Optional[bytes] = ..., map_point_ids: _Optional[bytes] = ..., scale_factors: _Optional[bytes] = ..., num_new_points: _Optional[int] = ..., new_point_ids: _Optional[bytes] = ..., new_points_world: _Optional[bytes] = ..., end_of_stream: _Optional[bool] = ..., count: _Optional[int] = ...) -> None: ...

class KeyframeCorrection(_message.Message):
    __slots__ = ("id", "T_world_cam", "num_keypoints", "map_point_ids")
    ID_FIELD_NUMBER: _ClassVar[int]
    T_WORLD_CAM_FIELD_NUMBER: _ClassVar[int]
    NUM_KEYPOINTS_FIELD_NUMBER: _ClassVar[int]
    MAP_POINT_IDS_FIELD_NUMBER: _ClassVar[int]
    id: int
    T_world_cam: RigidTransform
    num_keypoints: int
    map_point_ids: bytes
    def __init__(self, id: _Optional[int] = ..., T_world_cam: _Optional[_Union[RigidTransform, _Mapping]] = ..., num_keypoints: _Optional[int] = ..., map_point_ids: _Optional[bytes] = ...) -> None: ...

class MapUpdate(_message.Message):
    __slots__ = ("keyframe_id", "stamp_ns", "keyframes", "num_points", "point_ids", "p_world", "descriptors", "normals", "min_distance_m", "max_distance_m", "removed_point_ids", "removed_keyframe_ids", "end_of_stream", "count", "kind", "corrections_following", "normals_f32", "min_distance_m_f32", "max_distance_m_f32", "corrections_after_next_frame")
    KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    NUM_POINTS_FIELD_NUMBER: _ClassVar[int]
    POINT_IDS_FIELD_NUMBER: _ClassVar[int]
    P_WORLD_FIELD_NUMBER: _ClassVar[int]
    DESCRIPTORS_FIELD_NUMBER: _ClassVar[int]
    NORMALS_FIELD_NUMBER: _ClassVar[int]
    MIN_DISTANCE_M_FIELD_NUMBER: _ClassVar[int]
    MAX_DISTANCE_M_FIELD_NUMBER: _ClassVar[int]
    REMOVED_POINT_IDS_FIELD_NUMBER: _ClassVar[int]
    REMOVED_KEYFRAME_IDS_FIELD_NUMBER: _ClassVar[int]
    END_OF_STREAM_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    CORRECTIONS_FOLLOWING_FIELD_NUMBER: _ClassVar[int]
    NORMALS_F32_FIELD_NUMBER: _ClassVar[int]
    MIN_DISTANCE_M_F32_FIELD_NUMBER: _ClassVar[int]
    MAX_DISTANCE_M_F32_FIELD_NUMBER: _ClassVar[int]
    CORRECTIONS_AFTER_NEXT_FRAME_FIELD_NUMBER: _ClassVar[int]
    keyframe_id: int
    stamp_ns: int
    keyframes: _containers.RepeatedCompositeFieldContainer[KeyframeCorrection]
    num_points: int
    point_ids: bytes
    p_world: bytes
    descriptors: bytes
    normals: bytes
    min_distance_m: bytes
    max_distance_m: bytes
    removed_point_ids: bytes
    removed_keyframe_ids: bytes
    end_of_stream: bool
    count: int
    kind: MapUpdateKind
    corrections_following: int
    normals_f32: bytes
    min_distance_m_f32: bytes
    max_distance_m_f32: bytes
    corrections_after_next_frame: bool
    def __init__(self, keyframe_id: _Optional[int] = ..., stamp_ns: _Optional[int] = ..., keyframes: _Optional[_Iterable[_Union[KeyframeCorrection, _Mapping]]] = ..., num_points: _Optional[int] = ..., point_ids: _Optional[bytes] = ..., p_world: _Optional[bytes] = ..., descriptors: _Optional[bytes] = ..., normals: _Optional[bytes] = ..., min_distance_m: _Optional[bytes] = ..., max_distance_m: _Optional[bytes] = ..., removed_point_ids: _Optional[bytes] = ..., removed_keyframe_ids: _Optional[bytes] = ..., end_of_stream: _Optional[bool] = ..., count: _Optional[int] = ..., kind: _Optional[_Union[MapUpdateKind, str]] = ..., corrections_following: _Optional[int] = ..., normals_f32: _Optional[bytes] = ..., min_distance_m_f32: _Optional[bytes] = ..., max_distance_m_f32: _Optional[bytes] = ..., corrections_after_next_frame: _Optional[bool] = ...) -> None: ...

class Loop(_message.Message):
    __slots__ = ("keyframe_id", "stamp_ns", "loop_keyframe_id", "loop_stamp_ns", "accepted", "reason", "T_cur_loop", "scale", "inliers", "T_world_cur_before", "T_world_cur_after", "T_world_loop")
    KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    LOOP_KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    LOOP_STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    ACCEPTED_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    T_CUR_LOOP_FIELD_NUMBER: _ClassVar[int]
    SCALE_FIELD_NUMBER: _ClassVar[int]
    INLIERS_FIELD_NUMBER: _ClassVar[int]
    T_WORLD_CUR_BEFORE_FIELD_NUMBER: _ClassVar[int]
    T_WORLD_CUR_AFTER_FIELD_NUMBER: _ClassVar[int]
    T_WORLD_LOOP_FIELD_NUMBER: _ClassVar[int]
    keyframe_id: int
    stamp_ns: int
    loop_keyframe_id: int
    loop_stamp_ns: int
    accepted: bool
    reason: str
    T_cur_loop: RigidTransform
    scale: float
    inliers: int
    T_world_cur_before: RigidTransform
    T_world_cur_after: RigidTransform
    T_world_loop: RigidTransform
    def __init__(self, keyframe_id: _Optional[int] = ..., stamp_ns: _Optional[int] = ..., loop_keyframe_id: _Optional[int] = ..., loop_stamp_ns: _Optional[int] = ..., accepted: _Optional[bool] = ..., reason: _Optional[str] = ..., T_cur_loop: _Optional[_Union[RigidTransform, _Mapping]] = ..., scale: _Optional[float] = ..., inliers: _Optional[int] = ..., T_world_cur_before: _Optional[_Union[RigidTransform, _Mapping]] = ..., T_world_cur_after: _Optional[_Union[RigidTransform, _Mapping]] = ..., T_world_loop: _Optional[_Union[RigidTransform, _Mapping]] = ...) -> None: ...

class StageStatus(_message.Message):
    __slots__ = ("stage", "state", "processed", "step_ms", "queue_depth", "dropped", "detail", "timings_ms", "skipped")
    class TimingsMsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    class SkippedEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    STAGE_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    PROCESSED_FIELD_NUMBER: _ClassVar[int]
    STEP_MS_FIELD_NUMBER: _ClassVar[int]
    QUEUE_DEPTH_FIELD_NUMBER: _ClassVar[int]
    DROPPED_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    TIMINGS_MS_FIELD_NUMBER: _ClassVar[int]
    SKIPPED_FIELD_NUMBER: _ClassVar[int]
    stage: str
    state: StageState
    processed: int
    step_ms: float
    queue_depth: int
    dropped: int
    detail: str
    timings_ms: _containers.ScalarMap[str, float]
    skipped: _containers.ScalarMap[str, int]
    def __init__(self, stage: _Optional[str] = ..., state: _Optional[_Union[StageState, str]] = ..., processed: _Optional[int] = ..., step_ms: _Optional[float] = ..., queue_depth: _Optional[int] = ..., dropped: _Optional[int] = ..., detail: _Optional[str] = ..., timings_ms: _Optional[_Mapping[str, float]] = ..., skipped: _Optional[_Mapping[str, int]] = ...) -> None: ...

class KeyframeTrajectory(_message.Message):
    __slots__ = ("keyframes_processed", "finished", "num_keyframes", "keyframe_ids", "stamps_ns", "T_world_cam", "num_culled", "culled_keyframe_ids", "culled_stamps_ns", "culled_T_world_cam", "next_keyframe_id", "next_frontend_point_id")
    KEYFRAMES_PROCESSED_FIELD_NUMBER: _ClassVar[int]
    FINISHED_FIELD_NUMBER: _ClassVar[int]
    NUM_KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_IDS_FIELD_NUMBER: _ClassVar[int]
    STAMPS_NS_FIELD_NUMBER: _ClassVar[int]
    T_WORLD_CAM_FIELD_NUMBER: _ClassVar[int]
    NUM_CULLED_FIELD_NUMBER: _ClassVar[int]
    CULLED_KEYFRAME_IDS_FIELD_NUMBER: _ClassVar[int]
    CULLED_STAMPS_NS_FIELD_NUMBER: _ClassVar[int]
    CULLED_T_WORLD_CAM_FIELD_NUMBER: _ClassVar[int]
    NEXT_KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    NEXT_FRONTEND_POINT_ID_FIELD_NUMBER: _ClassVar[int]
    keyframes_processed: int
    finished: bool
    num_keyframes: int
    keyframe_ids: bytes
    stamps_ns: bytes
    T_world_cam: bytes
    num_culled: int
    culled_keyframe_ids: bytes
    culled_stamps_ns: bytes
    culled_T_world_cam: bytes
    next_keyframe_id: int
    next_frontend_point_id: int
    def __init__(self, keyframes_processed: _Optional[int] = ..., finished: _Optional[bool] = ..., num_keyframes: _Optional[int] = ..., keyframe_ids: _Optional[bytes] = ..., stamps_ns: _Optional[bytes] = ..., T_world_cam: _Optional[bytes] = ..., num_culled: _Optional[int] = ..., culled_keyframe_ids: _Optional[bytes] = ..., culled_stamps_ns: _Optional[bytes] = ..., culled_T_world_cam: _Optional[bytes] = ..., next_keyframe_id: _Optional[int] = ..., next_frontend_point_id: _Optional[int] = ...) -> None: ...

class MapSnapshot(_message.Message):
    __slots__ = ("keyframes", "num_points", "point_ids", "p_world")
    KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    NUM_POINTS_FIELD_NUMBER: _ClassVar[int]
    POINT_IDS_FIELD_NUMBER: _ClassVar[int]
    P_WORLD_FIELD_NUMBER: _ClassVar[int]
    keyframes: KeyframeTrajectory
    num_points: int
    point_ids: bytes
    p_world: bytes
    def __init__(self, keyframes: _Optional[_Union[KeyframeTrajectory, _Mapping]] = ..., num_points: _Optional[int] = ..., point_ids: _Optional[bytes] = ..., p_world: _Optional[bytes] = ...) -> None: ...

class RelocalisationQuery(_message.Message):
    __slots__ = ("stamp_ns", "num_words", "word_ids", "weights", "max_candidates", "max_neighbours", "window_keyframe_id")
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    NUM_WORDS_FIELD_NUMBER: _ClassVar[int]
    WORD_IDS_FIELD_NUMBER: _ClassVar[int]
    WEIGHTS_FIELD_NUMBER: _ClassVar[int]
    MAX_CANDIDATES_FIELD_NUMBER: _ClassVar[int]
    MAX_NEIGHBOURS_FIELD_NUMBER: _ClassVar[int]
    WINDOW_KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    stamp_ns: int
    num_words: int
    word_ids: bytes
    weights: bytes
    max_candidates: int
    max_neighbours: int
    window_keyframe_id: int
    def __init__(self, stamp_ns: _Optional[int] = ..., num_words: _Optional[int] = ..., word_ids: _Optional[bytes] = ..., weights: _Optional[bytes] = ..., max_candidates: _Optional[int] = ..., max_neighbours: _Optional[int] = ..., window_keyframe_id: _Optional[int] = ...) -> None: ...

class MapKeyframe(_message.Message):
    __slots__ = ("id", "stamp_ns", "T_world_cam", "num_keypoints", "keypoints_px", "levels", "angles_deg", "right_u", "depth_m", "descriptors", "map_point_ids", "scale_factors")
    ID_FIELD_NUMBER: _ClassVar[int]
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    T_WORLD_CAM_FIELD_NUMBER: _ClassVar[int]
    NUM_KEYPOINTS_FIELD_NUMBER: _ClassVar[int]
    KEYPOINTS_PX_FIELD_NUMBER: _ClassVar[int]
    LEVELS_FIELD_NUMBER: _ClassVar[int]
    ANGLES_DEG_FIELD_NUMBER: _ClassVar[int]
    RIGHT_U_FIELD_NUMBER: _ClassVar[int]
    DEPTH_M_FIELD_NUMBER: _ClassVar[int]
    DESCRIPTORS_FIELD_NUMBER: _ClassVar[int]
    MAP_POINT_IDS_FIELD_NUMBER: _ClassVar[int]
    SCALE_FACTORS_FIELD_NUMBER: _ClassVar[int]
    id: int
    stamp_ns: int
    T_world_cam: RigidTransform
    num_keypoints: int
    keypoints_px: bytes
    levels: bytes
    angles_deg: bytes
    right_u: bytes
    depth_m: bytes
    descriptors: bytes
    map_point_ids: bytes
    scale_factors: bytes
    def __init__(self, id: _Optional[int] = ..., stamp_ns: _Optional[int] = ..., T_world_cam: _Optional[_Union[RigidTransform, _Mapping]] = ..., num_keypoints: _Optional[int] = ..., keypoints_px: _Optional[bytes] = ..., levels: _Optional[bytes] = ..., angles_deg: _Optional[bytes] = ..., right_u: _Optional[bytes] = ..., depth_m: _Optional[bytes] = ..., descriptors: _Optional[bytes] = ..., map_point_ids: _Optional[bytes] = ..., scale_factors: _Optional[bytes] = ...) -> None: ...

class RelocalisationCandidate(_message.Message):
    __slots__ = ("keyframe_id", "score", "neighbour_ids")
    KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    SCORE_FIELD_NUMBER: _ClassVar[int]
    NEIGHBOUR_IDS_FIELD_NUMBER: _ClassVar[int]
    keyframe_id: int
    score: float
    neighbour_ids: bytes
    def __init__(self, keyframe_id: _Optional[int] = ..., score: _Optional[float] = ..., neighbour_ids: _Optional[bytes] = ...) -> None: ...

class RelocalisationCandidates(_message.Message):
    __slots__ = ("stamp_ns", "keyframes_processed", "candidates", "keyframes", "num_points", "point_ids", "p_world", "descriptors", "normals", "min_distance_m", "max_distance_m")
    STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    KEYFRAMES_PROCESSED_FIELD_NUMBER: _ClassVar[int]
    CANDIDATES_FIELD_NUMBER: _ClassVar[int]
    KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    NUM_POINTS_FIELD_NUMBER: _ClassVar[int]
    POINT_IDS_FIELD_NUMBER: _ClassVar[int]
    P_WORLD_FIELD_NUMBER: _ClassVar[int]
    DESCRIPTORS_FIELD_NUMBER: _ClassVar[int]
    NORMALS_FIELD_NUMBER: _ClassVar[int]
    MIN_DISTANCE_M_FIELD_NUMBER: _ClassVar[int]
    MAX_DISTANCE_M_FIELD_NUMBER: _ClassVar[int]
    stamp_ns: int
    keyframes_processed: int
    candidates: _containers.RepeatedCompositeFieldContainer[RelocalisationCandidate]
    keyframes: _containers.RepeatedCompositeFieldContainer[MapKeyframe]
    num_points: int
    point_ids: bytes
    p_world: bytes
    descriptors: bytes
    normals: bytes
    min_distance_m: bytes
    max_distance_m: bytes
    def __init__(self, stamp_ns: _Optional[int] = ..., keyframes_processed: _Optional[int] = ..., candidates: _Optional[_Iterable[_Union[RelocalisationCandidate, _Mapping]]] = ..., keyframes: _Optional[_Iterable[_Union[MapKeyframe, _Mapping]]] = ..., num_points: _Optional[int] = ..., point_ids: _Optional[bytes] = ..., p_world: _Optional[bytes] = ..., descriptors: _Optional[bytes] = ..., normals: _Optional[bytes] = ..., min_distance_m: _Optional[bytes] = ..., max_distance_m: _Optional[bytes] = ...) -> None: ...
