"""How tracking and the stages are doing: frontend/state per frame, <stage>/status per stage."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from zenslam.errors import MessageError
from zenslam.schemas import zenslam_pb2 as pb
from zenslam.schemas.codec.end_of_stream import EndOfStream
from zenslam.schemas.codec.packing import parse, transform_from_pb, transform_to_pb

TrackingStateName = Literal["ok", "lost", "initializing"]
StageStateName = Literal["starting", "running", "finished", "failed"]

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
        transform_to_pb(state.T_reference_cam, msg.T_reference_cam)
    return msg.SerializeToString()


def decode_tracking_state(data: bytes) -> TrackingStateMessage | EndOfStream:
    """Decode a frontend/state message."""
    msg = parse(pb.TrackingState, data)
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
        T_reference_cam=transform_from_pb(msg.T_reference_cam) if msg.HasField("T_reference_cam") else None,
        relocalised=msg.relocalised,
    )


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
    msg = parse(pb.StageStatus, data)
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
