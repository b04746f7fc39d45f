"""What the hub of ``zenslam run`` hears of its run: poses, tracking states, map updates, loops and
the stages' statuses, taken into a ``RunLog`` as they arrive, with a progress bar."""

from __future__ import annotations

import math
import time

from tqdm import tqdm

from zenslam.runtime import bus
from zenslam.schemas import codec, keys
from zenslam.service.ros2.run_bridge import Ros2RunBridge
from zenslam.service.run_config import RunConfig
from zenslam.service.run_output import RunLog


class RunFollower:
    """Receives frontend/state, frontend/pose, backend/map_update and the stages' statuses into a
    RunLog, with a progress bar; ``ros2`` (--ros2-publish) republishes the poses and keyframe path."""

    def __init__(
        self, session, run_id: str, config: RunConfig, total: int | None, progress: bool, ros2: Ros2RunBridge | None = None
    ):
        self.ros2 = ros2
        capacity = max(config.bus.lossless_queue, 256)
        # Lossless: every pose and state is needed for the trajectory and the metrics, every map update
        # and backend status for the keyframe counts and timings, every stage's last status to know
        # whether it was stopped. All are drained at every poll, so the stages never wait on this
        # process for long.
        self.poses = bus.subscribe(session, keys.frontend_pose(run_id), codec.decode_pose_in_frame, "lossless", capacity)
        self.states = bus.subscribe(session, keys.frontend_state(run_id), codec.decode_tracking_state, "lossless", capacity)
        update_capacity = max(config.frontend.map_update_queue, capacity)
        self.updates = bus.subscribe(session, keys.backend_map_update(run_id), codec.decode_map_update, "lossless", update_capacity)
        self.statuses = bus.subscribe(session, keys.all_status(run_id), codec.decode_stage_status, "lossless", capacity)
        self.loops = bus.subscribe(session, keys.backend_loop(run_id), codec.decode_loop, "lossless", capacity)
        self.log = RunLog(live=config.mode == "live")
        self.bar = tqdm(total=total, unit="frame", desc="tracking", disable=not progress)
        self.heard: dict[str, float] = {}  # stage -> when a message from it last arrived
        # Stages that have made progress (the frontend a tracking state, the backend a map update)
        # since they (re)started; until then they may be silent for bus.start_timeout_s.
        self.progressed: set[str] = set()
        self.start_timeout_s = config.bus.start_timeout_s
        self.source_sent = 0  # frames the source says it sent
        self.answered_at = -math.inf  # when the last map update arrived (time.monotonic())

    def poll(self, timeout_s: float) -> None:
        """Take what has arrived (waiting up to ``timeout_s`` seconds for a state)."""
        while (pose := self.poses.get(0)) is not None:
            self.log.add_pose(pose)
            if self.ros2 is not None:
                self.ros2.publish_pose(pose)
        self.poll_backend()
        state = self.states.get(timeout_s)
        if state is not None:
            self.heard["frontend"] = time.monotonic()
            self.progressed.add("frontend")
        if isinstance(state, codec.EndOfStream):
            self.log.ended = True
        elif state is not None:
            self.log.add_state(state)
            self.log.note_arrival(time.monotonic(), state=True)
            self.bar.update(1)
            self.bar.set_postfix(state=state.state, tracked=state.n_tracked, refresh=False)

    def poll_backend(self) -> None:
        """Take the map updates and stage statuses that have arrived."""
        updated = False
        while (update := self.updates.get(0)) is not None:
            self.log.add_map_update(update)
            if not isinstance(update, codec.EndOfStream):
                self.log.note_arrival(time.monotonic())
            updated = True
        if updated:
            self.heard["backend"] = self.answered_at = time.monotonic()
            self.progressed.add("backend")
            if self.ros2 is not None:
                self.ros2.publish_path(self.log.keyframe_trajectory())
        while (status := self.statuses.get(0)) is not None:
            self.log.add_status(status)
            self.heard[status.stage] = time.monotonic()
            if status.stage == "source":
                self.source_sent = max(self.source_sent, int(status.processed))
        while (loop := self.loops.get(0)) is not None:
            self.log.loops.append(loop)

    def silent_s(self, stage: str, since: float) -> float:
        """Seconds since ``stage`` was last heard, or since ``since`` when it has not been heard since then."""
        return time.monotonic() - max(self.heard.get(stage, since), since)

    def hang_limit_s(self, stage: str, hang_timeout_s: float) -> float:
        """The silence after which ``stage`` counts as hung: ``hang_timeout_s`` once it has made
        progress, at least ``bus.start_timeout_s`` while it starts (its first frame builds the tracker
        and its first keyframe the map, slow on a busy machine)."""
        return hang_timeout_s if stage in self.progressed else max(hang_timeout_s, self.start_timeout_s)

    def drain(self, until: float) -> None:
        """Keep taking messages until the poses announced by the states have all arrived, or ``until``."""
        while time.monotonic() < until and (not self.log.ended or self.log.missing_poses() > 0):
            self.poll(0.05)

    def close(self) -> None:
        self.bar.close()
        for inbox in (self.poses, self.states, self.updates, self.statuses):
            inbox.close()
