"""The source process: plays a Source onto sensor/frame, paced at the recorded rate or in lockstep.

Live mode sends frame i at its recorded time (scaled by ``source.rate``) whether or not anyone
keeps up, with DROP congestion control, like a camera. Lockstep mode keeps at most
``source.frames_in_flight`` frames sent without the frontend's frontend/state (frame i+1 is read
while frame i is tracked), with lossless delivery: every frame is tracked, in order, and the run is
deterministic. Either way the stream ends with an end-of-stream message. A frontend that crashes
and is restarted gets the frames in flight again (``_AnswerWindow``); a source that crashes is
restarted with ``--resume-after`` the newest frame tracked and goes on from the next.

Bad frames (unreadable, corrupt, stamps that do not increase; see sources.frame_stream) are not
sent: each is logged once as a warning and counted, and the counts by reason travel in the
``skipped`` map of every source/status message (the last one, "finished" or "failed", holds the
totals, which ``zenslam run`` writes to metrics.json as ``skipped_frames``). Lockstep never waits
for a frame it did not send. With ``source.strict`` the first bad frame ends the stream instead,
with a "failed" status whose detail names the frame and the problem.

A bus source (``zenoh:<key>``, sources/bus_source.py) is live input: frames come when another
program publishes them, each with its calibration, and are never paced here. The frontend's answers
still set the pace (the window of ``source.frames_in_flight``), and each frame sent is the newest
that arrived: those passed over are counted in the ``dropped`` field of every source/status, the
messages that could not be used in its ``skipped`` map (reasons ``malformed``, ``oversized``, ...).

The source writes no rerun recording: the frontend logs the images it tracks, under its keypoints.
Without the rerun SDK (and the pyarrow it loads) the source process holds less memory
(benchmarks/footprint.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ZenslamError
from zenslam.runtime import bus
from zenslam.runtime.stage import STOPPED, RunMode, StageStart, add_wait_for_argument, log_cpu_times, run_stage
from zenslam.schemas import codec, keys
from zenslam.service.pacer import Pacer as _Pacer
from zenslam.service.recorded_ground_truth import publish_ground_truth
from zenslam.service.sources import SensorFrame, is_bus_spec, open_bus_family, open_source
from zenslam.service.sources.bus_source import BusFrames
from zenslam.service.sources.config import SourceConfig
from zenslam.service.sources.faults import FaultInjector
from zenslam.service.sources.sensor_selection import mono_calibration
from zenslam.service.sources.frame_stream import SkippedFrame, frame_stream

logger = logging.getLogger(__name__)

STAGE = "source"
_STOPPED_SUBSCRIBER_WAIT_S = 5.0  # stopped at start-up: seconds to wait for the frontend's subscription


_RESEND_S = 5.0  # seconds between sends of the frames in flight to a restarted frontend, until it answers one


class _AnswerWindow:
    """Lockstep and pipelined: the frames sent and not yet answered by the frontend's state, oldest
    first, each with its message. A frontend that crashes loses the frames it held; when it comes
    back (restarted by the supervisor) they are sent again, oldest first, and again every
    ``_RESEND_S`` seconds until it answers one (a frame sent as its token arrives may not reach its
    new subscription; one it already has it refuses as not newer, answering with its newest state)."""

    def __init__(
        self, states: bus.Inbox, frontend: bus.Comebacks, resend: Callable[[bytes], None], timeout_s: float,
        restart_wait_s: float, should_stop: Callable[[], bool],
    ) -> None:
        self._states = states
        self._frontend = frontend
        self._resend = resend
        self._timeout_s = timeout_s  # source.answer_timeout_s
        self._restart_wait_s = restart_wait_s  # how long a gone frontend may take to come back
        self._should_stop = should_stop
        self._frames: deque[tuple[int, bytes]] = deque()
        self._resend_due: float | None = None  # after a frontend restart: when to send the frames again
        self.resent = 0  # frames sent again to a restarted frontend

    def __len__(self) -> int:
        return len(self._frames)

    def sent(self, index: int, message: bytes) -> None:
        self._frames.append((index, message))

    def wait_for_oldest(self) -> bool:
        """Wait for the frontend's state of the oldest frame in flight; False when the frontend ended
        its stream first (it was stopped: no more answers will come) or ``should_stop()`` turned true.

        Every ``timeout_s`` without the answer, the frontend's liveliness is checked: a running
        frontend may be waiting for the backend (a global BA after a loop runs in place in lockstep
        and grows with the map), so the wait goes on with a warning. A frontend that is gone gets
        ``restart_wait_s`` to come back before that is an error."""
        index = self._frames[0][0]
        deadline = time.monotonic() + self._timeout_s
        waited_s = 0.0
        gone_since: float | None = None
        while not self._should_stop():
            self._resend_after_a_restart()
            state = self._states.get(timeout_s=0.1)
            if isinstance(state, codec.TrackingStateMessage) and state.index >= index:
                self._resend_due = None  # the frontend takes frames
                # A later frame's state: the oldest went to a frontend that crashed and never reached its successor.
                while self._frames and self._frames[0][0] <= state.index:
                    self._frames.popleft()
                return True
            if isinstance(state, codec.EndOfStream):
                logger.info("the frontend ended its stream before answering frame %d: stopping", index)
                return False
            now = time.monotonic()
            if self._frontend.gone:
                gone_since = now if gone_since is None else gone_since
                if now - gone_since > self._restart_wait_s:
                    raise bus.BusError(
                        f"the frontend is gone with frame {index} unanswered and did not come back within "
                        f"{self._restart_wait_s:.0f} s (bus.start_timeout_s); check the frontend's log"
                    )
                deadline = now + self._timeout_s
                continue
            gone_since = None
            if now > deadline:
                waited_s += self._timeout_s
                logger.warning(
                    "no answer to frame %d for %.0f s; the frontend is running (it may wait for a long global BA "
                    "in the backend), waiting on", index, waited_s,
                )  # fmt: skip
                deadline = now + self._timeout_s
        return False

    def _resend_after_a_restart(self) -> None:
        now = time.monotonic()
        if self._frontend.returned():
            logger.warning("the frontend restarted: sending its %d frame(s) in flight again", len(self._frames))
        elif self._resend_due is None or now < self._resend_due or self._frontend.gone:
            return
        for _, message in self._frames:
            self._resend(message)
            self.resent += 1
        self._resend_due = now + _RESEND_S


def play(
    session: bus.Session,
    session_name: str,
    frames: Iterable[SensorFrame | codec.FrameMessage | SkippedFrame],
    calibration: PinholeCalibration | None,
    sensor: SensorKind | None,
    config: SourceConfig,
    should_stop: Callable[[], bool],
    source_name: str = "",
    mode: RunMode = "lockstep",
    start_timeout_s: float = 60.0,
    bus_input: BusFrames | None = None,
    sent_before: int = 0,
    recorded: bool = False,
) -> int:
    """Publish ``frames`` on sensor/frame, then an end-of-stream message; returns the frames sent.

    The caller has made sure the consumers are up. Stops early (still sending end-of-stream) when
    ``should_stop()`` turns true or after ``config.max_frames`` frames. A SkippedFrame is counted and
    not sent (with ``config.strict``, its error is raised instead, except for injected drops, which
    a real source could not notice). In lockstep and pipelined mode
    every frame waits for the frontend's answers (a window of ``config.frames_in_flight``); live
    mode plays at the recorded rate. ``start_timeout_s``: seconds to wait for the frontend's subscription.
    A codec.FrameMessage (a bus source's frame) brings its own calibration and sensor (then
    ``calibration`` and ``sensor`` may be None); ``bus_input``'s drops and rejected messages go
    into every status. ``sent_before``: frames the sources before this one sent in this run (a
    restart): they count towards ``config.max_frames`` and the returned and end-of-stream counts.
    ``recorded``: a recorder records the run; in lockstep and pipelined mode no frame is sent while
    it is gone (crashed, not restarted yet), for up to ``start_timeout_s``, so the recording misses
    only what was in flight when it died.
    """
    lockstep = mode != "live"
    key = keys.sensor_frame(session_name)
    # Lockstep frames must all arrive, in order; live frames may be dropped when a link is congested.
    frame_pub = bus.declare_publisher(session, key, codec.SENSOR_FRAME, "lossless" if lockstep else "live")
    # End of stream goes on the same key, lossless, so it arrives, and after the frames.
    end_pub = bus.declare_publisher(session, key, codec.SENSOR_FRAME, "lossless")
    status_pub = bus.declare_publisher(session, keys.status(session_name, STAGE), codec.STAGE_STATUS, "lossless")
    window = None
    if lockstep:
        # Lossless: the answer to every frame must be seen, or the source would wait forever.
        states = bus.subscribe(session, keys.frontend_state(session_name), codec.decode_tracking_state, "lossless", 64)
        frontend = bus.Comebacks(session, session_name, "frontend")
        window = _AnswerWindow(states, frontend, frame_pub.put, config.answer_timeout_s, start_timeout_s, should_stop)
    recorder = bus.Comebacks(session, session_name, "recorder") if recorded and lockstep else None
    if not bus.wait_for_subscribers(frame_pub, start_timeout_s, keep_waiting=lambda: not should_stop()):
        if not should_stop():
            raise bus.BusError(f"no subscriber to {key} within {start_timeout_s:.0f} s; is the frontend running?")
        # Stopped before the frontend's subscription reached this new session: the end of stream
        # must still reach the frontend, or it would wait for frames that never come.
        bus.wait_for_subscribers(frame_pub, min(start_timeout_s, _STOPPED_SUBSCRIBER_WAIT_S))
    pacer = _Pacer(0.0 if lockstep else config.rate, should_stop)
    log_cpu_times("at stream start")
    sent = sent_before
    skipped: Counter[str] = Counter()  # frames not sent, by reason
    answered = True  # False once the frontend stops answering (it ended its stream) or we are stopped

    def status(state: codec.StageStateName, step_ms: float = 0.0, detail: str = "") -> codec.StageStatusMessage:
        counts = dict(skipped) if bus_input is None else {**skipped, **bus_input.rejected}
        dropped = 0 if bus_input is None else bus_input.dropped
        return codec.StageStatusMessage(STAGE, state, sent, step_ms, dropped=dropped, detail=detail, skipped=counts)

    final = status("failed", detail="the source stopped on an unexpected error")
    try:
        for frame in frames:
            if not answered or should_stop() or (config.max_frames is not None and sent >= config.max_frames):
                break
            if isinstance(frame, SkippedFrame):
                _skip(frame, skipped, config.strict, source_name)
                status_pub.put(codec.encode_stage_status(status("running")))
                continue
            camera, sensor_kind = calibration, sensor
            if isinstance(frame, codec.FrameMessage):
                camera, sensor_kind, frame = frame.calibration, frame.sensor, frame.frame
            pacer.wait_for(frame.stamp_ns)
            if recorder is not None and not _wait_for_a_restarted_recorder(recorder, start_timeout_s, should_stop):
                recorder.close()
                recorder = None  # it did not come back: the run goes on unrecorded
            started = time.perf_counter()
            message = codec.encode_sensor_frame(frame, camera, sensor_kind, source_name, config.depth_encoding)
            frame_pub.put(message)
            sent += 1
            if window is not None:
                window.sent(frame.index, message)
            # States come lossless and in frame order: the oldest frame in flight is answered first.
            while answered and window is not None and len(window) >= config.frames_in_flight:
                answered = window.wait_for_oldest()
            status_pub.put(codec.encode_stage_status(status("running", (time.perf_counter() - started) * 1e3)))
        # The last answers. Stopped, we leave the frames in flight to the frontend: it tracks them before our end of stream.
        while answered and window is not None and len(window):
            answered = window.wait_for_oldest()
        detail = STOPPED if not answered or should_stop() else ""
        final = status("finished", detail=detail)
    except ZenslamError as exc:
        final = status("failed", detail=str(exc))
        raise
    finally:
        # The final status goes first: whoever sees the end of stream can already have the totals.
        status_pub.put(codec.encode_stage_status(final))
        end_pub.put(codec.encode_end_of_stream(codec.SENSOR_FRAME, sent))
        if window is not None:
            states.close()
            frontend.close()
        if recorder is not None:
            recorder.close()
    if final.skipped:
        logger.warning("skipped %d frame(s) or message(s): %s", sum(final.skipped.values()), dict(sorted(final.skipped.items())))
    if final.dropped:
        logger.info("dropped %d frame(s) that arrived while tracking was busy (the newest is tracked)", final.dropped)
    logger.info("sent %d frames and the end of stream on %s", sent, key)
    return sent


def _wait_for_a_restarted_recorder(recorder: bus.Comebacks, timeout_s: float, should_stop: Callable[[], bool]) -> bool:
    """While the recorder is gone (it crashed; the supervisor restarts it), wait up to ``timeout_s``
    seconds for it to come back before sending the next frame; False when it did not."""
    recorder.poll()
    if not recorder.gone:
        return True
    logger.warning("the recorder is gone: holding the next frame until it is back (up to %.0f s)", timeout_s)
    deadline = time.monotonic() + timeout_s
    while recorder.gone and not should_stop() and time.monotonic() < deadline:
        time.sleep(0.02)
        recorder.poll()
    if recorder.gone and not should_stop():
        logger.warning("the recorder did not come back within %.0f s: going on without it", timeout_s)
    recorder.returned()  # its comeback is taken
    return not recorder.gone


def _skip(frame: SkippedFrame, skipped: Counter[str], strict: bool, source_name: str) -> None:
    """Count a skipped frame and warn once, or (``strict``) raise its error."""
    if strict and frame.reason != "drop":
        raise frame.error
    skipped[frame.reason] += 1
    logger.warning(
        "%s: skipping %s [%s; %d frame(s) skipped so far]", source_name or "source", frame.error, frame.reason, sum(skipped.values())
    )


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``python -m zenslam.service.source_node --session S [--config FILE] [--connect EP] ...``."""
    return run_stage(STAGE, __doc__, _run, argv, _add_arguments)


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source", default=None, help="source spec overriding source.spec of the config")
    add_wait_for_argument(parser, "the first frame")
    parser.add_argument(
        "--resume-after", type=int, default=-1, metavar="INDEX",
        help="a restarted source: start at the first frame after INDEX, the newest one tracked (the supervisor passes it)",
    )
    parser.add_argument(
        "--sent-before", type=int, default=0, metavar="N",
        help="a restarted source: frames its predecessors sent (counted towards source.max_frames and the end of stream)",
    )
    parser.add_argument(
        "--publish-ground-truth", action="store_true",
        help="send the source's ground truth on source/ground_truth once the stages waited for are up (for the "
        "recorder; ``zenslam run`` sends it itself, a source started with ``zenslam stage`` does)",
    )


def _run(stage: StageStart) -> None:
    """The source process: its source opened, then played onto the run's session once the stages it feeds are up."""
    args = stage.args
    config = stage.section(STAGE, SourceConfig)
    spec = args.source or config.spec
    if is_bus_spec(spec):
        _play_bus_input(stage, spec, config)
        return
    source = open_source(spec, config.sensor)
    calibration = config.calibration or source.calibration
    if source.sensor == "mono":
        calibration = mono_calibration(calibration)  # settings files of stereo cameras state a baseline

    with stage.open_session() as session, bus.declare_alive(session, args.session, STAGE):
        stage.require_alive(session, args.wait_for)
        if args.publish_ground_truth and (ground_truth := source.ground_truth()) is not None:
            publish_ground_truth(session, args.session, ground_truth)
        injector = FaultInjector(config.faults)
        for fault in injector.beyond(len(source)):
            logger.warning("source.faults %s starts past the last frame (%d); it is never applied", fault.describe(), len(source) - 1)
        if args.restart:
            logger.warning(
                "restart %d: resuming after frame %d, the newest tracked (%d frame(s) sent before)",
                args.restart, args.resume_after, args.sent_before,
            )  # fmt: skip
        frames = frame_stream(source, injector, start=args.resume_after + 1)
        play(
            session, args.session, frames, calibration, source.sensor, config, stage.stop, source.name,
            mode=stage.mode(), start_timeout_s=stage.bus_config.start_timeout_s, sent_before=args.sent_before,
            recorded="recorder" in args.wait_for,
        )


def _play_bus_input(stage: StageStart, spec: str, config: SourceConfig) -> None:
    """Play the frames another program publishes (a bus source): the run's session also connects to
    ``source.connect``, where the publisher is; frames are taken as they come (never paced)."""
    args = stage.args
    family = open_bus_family(spec, config.ros_domain)
    with stage.open_session(config.connect) as session, bus.declare_alive(session, args.session, STAGE):
        stage.require_alive(session, args.wait_for)
        bus_input = BusFrames(session, family, config, stage.stop)
        live = dataclasses.replace(config, rate=0.0)  # the publisher keeps the time
        play(
            session, args.session, bus_input.frames(), None, None, live, stage.stop, family.name,
            mode=stage.mode(), start_timeout_s=stage.bus_config.start_timeout_s, bus_input=bus_input,
        )


if __name__ == "__main__":
    sys.exit(main())
