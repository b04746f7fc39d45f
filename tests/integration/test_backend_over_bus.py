"""Source, frontend and backend as real processes over zenoh on loopback, on a short synthetic sequence.

The test process is the hub and follows the run as ``zenslam run`` does: it counts the keyframes
the frontend announces and the backend's map updates, and queries backend/trajectory and
backend/map while the stages are still running.
"""

from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from zenslam.backend.config import BackendConfig
from zenslam.runtime.backend_queries import query_map, query_trajectory
from zenslam.runtime import bus
from zenslam.runtime.stage import RunMode
from zenslam.runtime.supervisor import ProcessSpec, Supervisor
from zenslam.schemas import codec, keys
from zenslam.service.run_config import RunConfig, SourceConfig
from zenslam.service.run_output import prepare_run_dir, write_config

pytestmark = pytest.mark.integration

LOCKSTEP_FRAMES = 30
LIVE_FRAMES = 60  # 3 s of the 20 Hz synthetic loop at its recorded rate
RUN_TIMEOUT_S = 240.0


@dataclass
class FollowedRun:
    """What the test process saw of one run."""

    states: list[codec.TrackingStateMessage] = field(default_factory=list)
    updates: list[int] = field(default_factory=list)  # keyframe id of each answer to a keyframe, in arrival order
    end_count: int | None = None  # the count in the backend's end of stream
    during_trajectory: codec.KeyframeTrajectoryMessage | None = None  # asked while the stages ran
    during_map: codec.MapSnapshotMessage | None = None
    frontend_running_after_queries: bool = False
    final_trajectory: codec.KeyframeTrajectoryMessage | None = None
    exit_codes: dict[str, int | None] = field(default_factory=dict)


def _follow(tmp_path: Path, run_id: str, source: SourceConfig, mode: RunMode = "lockstep") -> FollowedRun:
    config = RunConfig(mode=mode, source=source)
    run_dir = prepare_run_dir(tmp_path, run_id)
    config_path = write_config(run_dir, config)
    hub = bus.free_tcp_endpoint()
    seen = FollowedRun()
    with bus.open_session(bus.BusConfig(listen=(hub,))) as session:
        states = bus.subscribe(session, keys.frontend_state(run_id), codec.decode_tracking_state, "lossless", 512)
        updates = bus.subscribe(session, keys.backend_map_update(run_id), codec.decode_map_update, "lossless", 512)
        try:
            with Supervisor(run_dir, run_id, config_path, hub) as supervisor:
                supervisor.start(ProcessSpec("backend", "zenslam.backend.node"))
                supervisor.wait_until_alive(session, ["backend"], 60.0)
                supervisor.start(ProcessSpec("frontend", "zenslam.frontend.node", ("--map-updates", "--wait-for", "backend")))
                supervisor.wait_until_alive(session, ["frontend"], 60.0)
                supervisor.start(ProcessSpec("source", "zenslam.service.source_node", ("--wait-for", "frontend")))
                deadline = time.monotonic() + RUN_TIMEOUT_S
                while seen.end_count is None:
                    assert time.monotonic() < deadline, "the run did not end in time"
                    supervisor.check()
                    while (state := states.get(0)) is not None:
                        if not isinstance(state, codec.EndOfStream):
                            seen.states.append(state)
                    update = updates.get(timeout_s=0.05)
                    if isinstance(update, codec.EndOfStream):
                        seen.end_count = update.count
                    elif update is not None and update.answers_keyframe:  # not the corrections after an answer
                        seen.updates.append(update.keyframe_id)
                    if len(seen.updates) == 2 and seen.during_trajectory is None:
                        seen.during_trajectory = query_trajectory(session, run_id, timeout_s=10.0)
                        seen.during_map = query_map(session, run_id, timeout_s=10.0)
                        seen.frontend_running_after_queries = supervisor.returncode("frontend") is None
                while (state := states.get(timeout_s=1.0)) is not None:
                    if not isinstance(state, codec.EndOfStream):
                        seen.states.append(state)
                seen.final_trajectory = query_trajectory(session, run_id, timeout_s=10.0)
                supervisor.request_stop(["backend"])
                seen.exit_codes = supervisor.wait_exit(30.0)
        finally:
            states.close()
            updates.close()
    return seen


@pytest.fixture(scope="module")
def lockstep_run(tmp_path_factory) -> FollowedRun:
    source = SourceConfig(spec="synthetic", max_frames=LOCKSTEP_FRAMES)
    return _follow(tmp_path_factory.mktemp("recordings"), "it-backend-lockstep", source)


def test_every_keyframe_gets_a_map_update_in_order(lockstep_run):
    run = lockstep_run
    assert [s.index for s in run.states] == list(range(LOCKSTEP_FRAMES))
    sent = [s.keyframe_id for s in run.states if s.keyframe_id >= 0]
    assert len(sent) >= 3
    assert run.updates == sent
    assert run.end_count == len(sent)
    assert run.exit_codes == {"backend": 0, "frontend": 0, "source": 0}


def test_the_queryables_answer_while_the_stages_run(lockstep_run):
    run = lockstep_run
    assert run.frontend_running_after_queries
    during = run.during_trajectory
    assert during is not None and not during.finished
    assert 2 <= during.keyframes_processed < len(run.updates)
    assert set(during.keyframe_ids.tolist()) <= set(run.updates[: during.keyframes_processed])
    snapshot = run.during_map
    assert snapshot is not None and len(snapshot.point_ids) > 100
    assert np.isfinite(snapshot.p_world).all()
    assert (np.diff(snapshot.point_ids) > 0).all()


def test_the_final_trajectory_has_every_kept_keyframe(lockstep_run):
    run = lockstep_run
    final = run.final_trajectory
    assert final is not None and final.finished and final.keyframes_processed == len(run.updates)
    assert set(final.keyframe_ids.tolist()) <= set(run.updates) and final.keyframe_ids[0] == 0
    stamps = {s.keyframe_id: s.stamp_ns for s in run.states if s.keyframe_id >= 0}
    assert final.stamps_ns.tolist() == [stamps[k] for k in final.keyframe_ids.tolist()]
    np.testing.assert_allclose(final.T_world_cam[0], np.eye(4), atol=1e-9)  # the first keyframe anchors the map


def test_live_mode_processes_every_keyframe(tmp_path):
    source = SourceConfig(spec="synthetic", rate=1.0, max_frames=LIVE_FRAMES)
    run = _follow(tmp_path, "it-backend-live", source, mode="live")
    sent = [s.keyframe_id for s in run.states if s.keyframe_id >= 0]
    # How many frames a live frontend keeps up with depends on the machine; it may skip frames, never
    # keyframes' updates. What it tracked came in order.
    indices = [s.index for s in run.states]
    assert indices == sorted(set(indices)) and set(indices) <= set(range(LIVE_FRAMES))
    assert len(sent) >= 2
    assert sorted(run.updates) == sent and run.end_count == len(sent)
    assert run.final_trajectory is not None and run.final_trajectory.keyframes_processed == len(sent)
    assert run.exit_codes == {"backend": 0, "frontend": 0, "source": 0}
    # A live camera does not wait for tracking: mapping yields the CPU to it (the niceness it logs is ours plus its increment).
    said = re.findall(r"niceness (-?\d+): ", (tmp_path / "it-backend-live" / "logs" / "backend.log").read_text())
    assert said == [str(min(os.nice(0) + BackendConfig().nice, 19))]
