"""What the backend sends: one keyframe's ``StepOutput`` and the publishers that put it, the loop
messages and the stage's status on the bus."""

from __future__ import annotations

from dataclasses import dataclass, field


from zenslam.runtime import bus
from zenslam.schemas import codec, keys
from zenslam.schemas.map_update import MapUpdate

STAGE = "backend"  # the stage's name on the bus: its status key, its liveliness token, its recording


@dataclass(frozen=True)
class StepOutput:
    """What one keyframe produced: its answer, then any corrections (a closed loop), and the loop
    candidates that reached verification."""

    updates: list[MapUpdate]  # the answer (kind keyframe) first, then corrections in order
    loops: list[codec.LoopMessage] = field(default_factory=list)


class BackendOutputs:
    """The backend's publishers, all lossless: every update and status must arrive, in order."""

    def __init__(self, session: bus.Session, session_name: str) -> None:
        self.update = bus.declare_publisher(session, keys.backend_map_update(session_name), codec.MAP_UPDATE, "lossless")
        self.status = bus.declare_publisher(session, keys.status(session_name, STAGE), codec.STAGE_STATUS, "lossless")
        self.loop = bus.declare_publisher(session, keys.backend_loop(session_name), codec.LOOP, "lossless")

    def send_step(self, output: StepOutput) -> None:
        """The loop messages, then the answer and its corrections, in order."""
        for loop in output.loops:
            self.loop.put(codec.encode_loop(loop))
        for update in output.updates:
            self.update.put(codec.encode_map_update(update))

    def send_status(self, status: codec.StageStatusMessage) -> None:
        self.status.put(codec.encode_stage_status(status))
