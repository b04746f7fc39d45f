"""The stages of a ``zenslam run`` under its hub: started in order, followed to the end of the stream,
watched for hangs and failures (restarted where they can recover), and stopped in the order the
data flows, so that nothing already sent is lost."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from zenslam.errors import ProcessError
from zenslam.runtime.backend_queries import query_trajectory
from zenslam.runtime.stop import StopFlag
from zenslam.runtime.supervisor import ProcessSpec, SupervisionConfig, Supervisor
from zenslam.service.recorded_ground_truth import publish_ground_truth
from zenslam.service.recorder_config import RECORDING_NAME
from zenslam.service.run_config import RunConfig
from zenslam.service.run_follower import RunFollower
from zenslam.service.run_output import RunLog
from zenslam.service.stages import STAGE_MODULES, stage_args
from zenslam.trajectory import Trajectory

logger = logging.getLogger(__name__)

POSE_GRACE_S = 5.0  # seconds to wait, after the end of stream, for poses still in flight
_STOP_GRACE_S = 30.0  # seconds a stage told to stop gets to end its stream before the next step of stopping
_CAUGHT_UP_WAIT_S = 5.0  # interrupted: seconds to wait for a backend with no keyframe left to end its stream
EXIT_WAIT_S = 30.0  # seconds the stages get to exit by themselves after the end of stream
_QUERY_TIMEOUT_S = 10.0  # seconds to wait for the backend's answer to the final trajectory query


def watch_for_hang(follower: RunFollower, supervisor: Supervisor, hang_timeout_s: float, since: float, stop: StopFlag) -> None:
    """Kill a stage whose input waits while it has said nothing for ``hang_timeout_s`` seconds (0:
    never; a stage still starting gets ``bus.start_timeout_s``), counted from ``since`` at the latest
    (when following began): the backend while keyframes or announced corrections wait for it; the frontend while frames the
    source sent wait for it, unless it waits for the backend's answers itself. The next ``_check_restarts``
    then restarts it or fails the run, as for a crash. The frontend's silence counts from the
    backend's last answer at the latest: in lockstep it is silent while it waits for one (for as long
    as a hung backend takes to be caught and rebuilt), and it needs a moment to go on once one came."""
    if hang_timeout_s <= 0 or stop():
        return
    backend_silent_s = follower.silent_s("backend", since)
    frontend_silent_s = follower.silent_s("frontend", max(since, follower.answered_at))
    backend_limit_s = follower.hang_limit_s("backend", hang_timeout_s)
    frontend_limit_s = follower.hang_limit_s("frontend", hang_timeout_s)
    if backend_silent_s < backend_limit_s and frontend_silent_s < frontend_limit_s:
        return  # the usual case, decided before counting the log's frames and keyframes
    log = follower.log
    counts = log.keyframe_counts()
    # The backend owes work while a keyframe waits for its answer or an answer's announced
    # corrections are still to come (a lockstep frontend waits for those too).
    owed = counts["processed"] < counts["sent"] or log.corrections_owed > 0
    keyframes_wait = not log.backend_ended and (owed or (log.ended and counts["sent"] > 0))
    if keyframes_wait and backend_silent_s >= backend_limit_s:
        supervisor.kill_hung("backend", backend_silent_s)
        return
    frames_wait = not log.ended and follower.source_sent > len(log.frames)
    if frames_wait and not keyframes_wait and frontend_silent_s >= frontend_limit_s:
        supervisor.kill_hung("frontend", frontend_silent_s)


def _check_restarts(supervisor: Supervisor, stop: StopFlag, follower: RunFollower, supervision: SupervisionConfig) -> None:
    """Restart a failed stage that can recover (``supervision.max_restarts``), noting it in the log;
    raise for any other failed stage. Interrupted, neither: the run winds down and ``report_exits`` says."""
    if stop():
        return
    frame = len(follower.log.frames)
    last_index = follower.log.frames.newest_index()  # the newest frame tracked: what a frontend restart lost follows it
    # A restarted source resumes at the first frame not yet tracked; what its predecessors sent counts
    # towards source.max_frames (frames in flight then reach the frontend twice: it refuses the second
    # copy and answers it with its newest state).
    resume = {"source": ("--resume-after", str(last_index), "--sent-before", str(max(frame, 0)))}
    for restarted in supervisor.restart_failed(supervision, resume):
        follower.log.restarts.append({**restarted, "frame": frame, "last_frame_index": last_index})
        stage = str(restarted["stage"])
        follower.heard[stage] = time.monotonic()
        follower.progressed.discard(stage)  # starting again: watched as a stage that starts


def _check_source(log: RunLog) -> None:
    """Raise ProcessError with the source's own words when it reported a failure (e.g. a bad frame in strict mode)."""
    if log.source_failure is not None:
        raise ProcessError(f"the source stopped the run: {log.source_failure}")


def _start_recorder(supervisor: Supervisor, session, config: RunConfig, run_dir: Path, keep_waiting) -> None:
    """Start the recorder (before any other stage) and wait for it to listen.

    It follows the source, frontend and backend and exits by itself once they have all exited, so
    the supervisor's ``wait_exit`` also waits for the recording to be finished. Restartable: a
    restarted recorder carries its predecessor's file over (``recorder.set_aside``).
    """
    args = ("--output", str(run_dir / RECORDING_NAME), *stage_args("recorder", recorder=True))
    supervisor.start(ProcessSpec("recorder", STAGE_MODULES["recorder"], args, restartable=True))
    supervisor.wait_until_alive(session, ["recorder"], config.bus.start_timeout_s, keep_waiting)


def start_stages(
    supervisor: Supervisor, session, config: RunConfig, run_dir: Path, stop: StopFlag, ground_truth: Trajectory | None,
    follower: RunFollower, wait_for: tuple[str, ...] = (),
) -> bool:
    """Start the recorder, backend, frontend and source, each once the one it needs is up; False when
    interrupted first (those started are then told to stop, and no other is started). ``ground_truth``
    (the source's) goes into the recording, so a replay of it is scored too. ``wait_for``: clients'
    liveliness names the publishing stages wait for (``--wait-for``)."""
    timeout_s = config.bus.start_timeout_s
    if not stop() and config.recorder.enabled:
        # The recorder comes first, and each stage waits until it sees the recorder's token before
        # publishing: then the recorder's subscription has reached it too.
        _start_recorder(supervisor, session, config, run_dir, stop.keep_going)
        if ground_truth is not None:
            publish_ground_truth(session, supervisor.session_name, ground_truth)
    recorder = config.recorder.enabled
    # A restarted backend rebuilds its map from its journal; a restarted frontend relocalises into the
    # backend's map (the source sends it the frames in flight again); a restarted source resumes at
    # the first frame not yet tracked (a bus source takes the frames published from then on). The
    # recorder's restarts are set up with it (``_start_recorder``).
    restartable = {"backend", "source"} if config.backend.journal else {"source"}
    if config.frontend.tracking.relocalisation.enabled:
        restartable.add("frontend")
    stages = [
        ProcessSpec(name, STAGE_MODULES[name], stage_args(name, recorder, wait_for), restartable=name in restartable)
        for name in ("backend", "frontend", "source")
    ]
    for spec in stages:
        if stop():
            supervisor.request_stop()
            return False
        supervisor.start(spec)
        while spec.name != "source":  # the source is followed through the frontend's states
            try:
                supervisor.wait_until_alive(session, [spec.name], timeout_s, stop.keep_going)
                break
            except ProcessError:
                if stop() or not supervisor.failures():  # interrupted, or up too slowly: not a crash
                    raise
                _check_restarts(supervisor, stop, follower, config.supervision)  # a stage that died starting: restarted, or raised
    return True


def follow_frontend(follower: RunFollower, supervisor: Supervisor, stop: StopFlag, supervision: SupervisionConfig) -> None:
    """Follow the run until the frontend's end of stream, then take the poses still in flight.

    On an interrupt only the source is stopped: it ends its stream at once, and the frontend tracks
    the frames already sent, publishes their poses and ends its own stream. The frontend itself is
    stopped (it finishes the frame in hand) when it has not ended ``_STOP_GRACE_S`` seconds later,
    or at a second Ctrl-C.
    """
    source_told = frontend_told = None  # when each was told to stop
    since = time.monotonic()
    while not follower.log.ended:
        now = time.monotonic()
        if stop() and source_told is None:
            supervisor.request_stop(["source"])
            source_told = now
        if source_told is not None and frontend_told is None and (stop.signals > 1 or now - source_told > _STOP_GRACE_S):
            supervisor.request_stop(["frontend"])
            frontend_told = now
        if frontend_told is not None and now - frontend_told > _STOP_GRACE_S:
            logger.warning("the frontend did not end its stream within %.0f s of being told to stop", _STOP_GRACE_S)
            break
        watch_for_hang(follower, supervisor, supervision.hang_timeout_s, since, stop)
        _check_restarts(supervisor, stop, follower, supervision)
        if supervisor.returncode("frontend") == 0 or (stop() and supervisor.returncode("frontend") is not None):
            follower.drain(time.monotonic() + 1.0)
            if not follower.log.ended and not stop():
                raise ProcessError(f"the frontend exited before the end of stream:\n{supervisor.log_tail('frontend')}")
            break
        _check_source(follower.log)
        follower.poll(0.05)
    follower.drain(time.monotonic() + POSE_GRACE_S)
    _check_source(follower.log)


def follow_backend(follower: RunFollower, supervisor: Supervisor, stop: StopFlag, supervision: SupervisionConfig) -> None:
    """Wait until the backend has processed every keyframe (its map-update stream ended). Interrupted,
    wait only while it has caught up with the keyframes sent (its end of stream is on its way),
    for at most ``_CAUGHT_UP_WAIT_S`` seconds."""
    counts = follower.log.keyframe_counts()
    if not follower.log.backend_ended and not stop():
        logger.info("waiting for the backend: %d of %d keyframes processed", counts["processed"], counts["sent"])
    stopped_at = None
    since = time.monotonic()
    while not follower.log.backend_ended:
        if stop():
            stopped_at = time.monotonic() if stopped_at is None else stopped_at
            counts = follower.log.keyframe_counts()
            if counts["processed"] < counts["sent"] or time.monotonic() - stopped_at > _CAUGHT_UP_WAIT_S:
                return
        watch_for_hang(follower, supervisor, supervision.hang_timeout_s, since, stop)
        _check_restarts(supervisor, stop, follower, supervision)
        if supervisor.returncode("backend") == 0 or (stop() and supervisor.returncode("backend") is not None):
            follower.poll_backend()
            if not follower.log.backend_ended and not stop():
                raise ProcessError(f"the backend exited before the end of its stream:\n{supervisor.log_tail('backend')}")
            break
        follower.poll_backend()
        time.sleep(0.02)
    follower.poll_backend()  # statuses sent with the end of stream


def stop_backend(follower: RunFollower, supervisor: Supervisor, session, run_id: str) -> None:
    """Ask a backend that ended its stream for its keyframe poses (it lingers to answer queries), then
    tell it to go; one still mapping (interrupted) ends its stream after the keyframe in hand, and
    keyframes.tum then has the frontend's keyframes with the backend's updates applied. Takes its
    last updates and statuses."""
    log = follower.log
    if log.backend_ended and "backend" not in log.stopped_stages and supervisor.returncode("backend") is None:
        log.backend_keyframes = query_trajectory(session, run_id, _QUERY_TIMEOUT_S)
        if log.backend_keyframes is None:
            logger.warning("the backend did not answer the trajectory query; keyframes.tum has the frontend's keyframes")
    supervisor.request_stop(["backend"])
    deadline = time.monotonic() + _STOP_GRACE_S
    while not log.backend_ended and supervisor.returncode("backend") is None and time.monotonic() < deadline:
        follower.poll_backend()
        time.sleep(0.02)
    follower.poll_backend()


def report_exits(supervisor: Supervisor, stop: StopFlag, statuses: dict[str, int | None]) -> None:
    """Raise for a failed stage; interrupted, warn instead (what was tracked is still written)."""
    if not stop():
        supervisor.check()  # the stream is over: a stage that failed now is not restarted
    for name, code in statuses.items():
        if code not in (None, 0):
            logger.warning("%s exited with status %s while the run stopped; see %s", name, code, supervisor.run_dir / "logs")
    stuck = [name for name, code in statuses.items() if code is None]
    if stuck:
        logger.warning("stage(s) %s still running %.0f s after the end of stream; stopping them", stuck, EXIT_WAIT_S)
