"""The frontend process: sensor/frame in, tracking out (frontend/pose, frontend/state, frontend/keyframe).

``FrontendNode.handle`` turns one decoded frame into the encoded messages to send and is testable
without the bus; ``serve`` is the loop that receives, handles and publishes. The tracking itself
is ``zenslam.frontend.pipeline.FrontendPipeline``, built on the first frame from the calibration
and sensor kind that every sensor/frame message carries.

With a backend (``serve(..., map_updates=...)``), the backend's backend/map_update messages
(``map_update_inbox``) are applied to the pipeline's map cache through its ``map_sync``: in live
mode every update that has arrived is applied before the next frame is tracked; in lockstep,
after publishing a keyframe the frontend waits for the backend's update of that keyframe before
it tracks another frame, so the run is deterministic; meanwhile it builds the next frame (ORB,
stereo or depth: images only, no map) if that frame has arrived, so the backend's mapping and the
frontend's feature extraction share the two cores. Pipelined
mode (every frame, in order, as in lockstep) applies updates as live mode does. With a backend, a
lost frame asks it for relocalisation candidates on backend/relocalisation (``RelocalisationQueries``)
and waits for the answer: in lockstep the backend is idle between keyframes, so the answer, and
the run, stay deterministic.

A frontend restarted after a crash (``--restart N``) asks the backend for the first keyframe and
point ids past its map (``continuing_config``), starts lost and relocalises into the backend's map,
as a run from a saved map does; answers to its predecessor's keyframes are not applied.

A frame whose index is not after the last one tracked (sent again by a restarted source, or to a
restarted frontend) is refused and answered with the newest frame's state once more: the source
waits for a state at or past each frame it sent, and a subscriber to frontend/state can see a
state twice then (same message, same index).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import CalibrationError, ZenslamError
from zenslam.frontend.config import FrontendConfig, entering_map
from zenslam.frontend.kernel_warm_up import warm_up_kernels
from zenslam.frontend.map_update_inbox import MapUpdateInbox
from zenslam.runtime import bus
from zenslam.runtime.stage import STOPPED, RunMode, StageStart, add_wait_for_argument, log_cpu_times, run_stage
from zenslam.schemas import codec, keys
from zenslam.schemas.map_update import MapUpdate
from zenslam.schemas.relocalisation import RelocalisationCandidates, RelocalisationQuery

if TYPE_CHECKING:
    from zenslam.frontend.keyframe import KeyFrame
    from zenslam.frontend.rerun_log import FrontendLog
    from zenslam.frontend.tracking_state import TrackingOutput

logger = logging.getLogger(__name__)

STAGE = "frontend"


class MapUpdateTarget(Protocol):
    """Applies the backend's map updates to a frontend's map cache (``map_sync.MapSync``)."""

    def apply(self, update: MapUpdate) -> None: ...


class Pipeline(Protocol):
    """What the node needs of the tracker (FrontendPipeline satisfies it)."""

    def prepare(
        self, index: int, stamp_ns: int, left: np.ndarray, right: np.ndarray | None = None, depth_m: np.ndarray | None = None
    ) -> Any: ...

    def step(
        self, index: int, stamp_ns: int, left: np.ndarray, right: np.ndarray | None = None,
        depth_m: np.ndarray | None = None, keyframes_in_flight: int = 0, prepared: Any = None,
        candidates: CandidateSource | None = None,
    ) -> Any: ...

    @property
    def map_sync(self) -> MapUpdateTarget:
        """What applies the backend's map updates to the pipeline's map cache."""
        ...

    @property
    def may_ask_backend(self) -> bool:
        """Whether the next ``step`` may call its ``candidates`` (tracking lost, or in a saved map)."""
        ...


PipelineFactory = Callable[[PinholeCalibration, SensorKind], Pipeline]
# Relocalisation candidates for a lost frame's bag of words; None when the backend did not answer.
CandidateSource = Callable[[RelocalisationQuery], "RelocalisationCandidates | None"]


@dataclass(frozen=True)
class FrontendMessages:
    """The encoded messages one frame produces, in the order they are sent."""

    keyframes: tuple[bytes, ...]  # frontend/keyframe: the keyframes made at this frame's step, in order
    pose: bytes | None  # frontend/pose, when tracking gave a pose
    state: bytes  # frontend/state, always (sent last: it tells lockstep sources the frame is done)
    step_ms: float  # wall time of the tracking step, milliseconds
    keyframe_id: int = -1  # the keyframe made at this frame, -1 if none
    keyframe_ids: tuple[int, ...] = ()  # the id of each of ``keyframes``


def keyframe_message(keyframe: KeyFrame, calibration: PinholeCalibration, sensor: SensorKind) -> codec.KeyframeMessage:
    """The bus form of the pipeline's KeyFrame."""
    return codec.KeyframeMessage(
        id=int(keyframe.id),
        stamp_ns=int(keyframe.stamp_ns),
        frame_index=int(keyframe.frame_index),
        T_world_cam=np.asarray(keyframe.T_world_cam),
        calibration=calibration,
        sensor=sensor,
        keypoints_px=keyframe.px,
        levels=keyframe.level,
        angles_deg=keyframe.angle_deg,
        right_u=keyframe.right_u,
        depth_m=keyframe.depth_m,
        descriptors=keyframe.descriptors,
        map_point_ids=keyframe.map_point_ids,
        scale_factors=np.asarray(keyframe.features.scale_factors, dtype=np.float64),
        new_point_ids=keyframe.new_point_ids,
        new_points_world=np.asarray(keyframe.new_points_world).reshape(-1, 3),
    )


class FrontendNode:
    """Runs the pipeline on decoded frames and encodes its outputs; no transport in here."""

    def __init__(self, make_pipeline: PipelineFactory, rerun: FrontendLog | None = None):
        self._make_pipeline = make_pipeline
        self.rerun = rerun  # logs each frame's keypoints, pose, state and timings to the stage's .rrd
        self._unlogged: tuple[codec.FrameMessage, TrackingOutput] | None = None  # handled, not yet logged to rerun
        self._pipeline: Pipeline | None = None
        self._map_sync: MapUpdateTarget | None = None  # the pipeline's, applied to in one call per update
        self._camera: tuple[PinholeCalibration, SensorKind] | None = None
        self.frames = 0  # frames handled
        self.keyframes = 0  # keyframes sent
        self.skipped = 0  # frames never seen (gaps in the indices: dropped in live mode)
        self.built_ahead = 0  # frames whose ORB/stereo was built while waiting for the backend (lockstep)
        self.updates_applied = 0  # backend map updates applied to the pipeline's map
        self.answers_applied = 0  # of those, answers to this frontend's keyframes (corrections are not)
        self.tracks_backend = False  # set by ``serve`` when the backend's map updates are applied
        # Set by ``serve``: the last keyframe was answered before its local BA, whose correction
        # is not applied yet (lockstep with backend.answer_before_local_ba): local mapping is busy.
        self.local_ba_running = False
        self.backend_gone = False  # set by ``serve``: the backend crashed and is not back yet
        self.candidates: CandidateSource | None = None  # set by ``serve``: asks the backend where a lost frame is
        self.refused = 0  # frames refused by ``refusal`` (never tracked)
        self.keyframes_before = 0  # a restarted frontend: keyframes the backend had from its predecessors
        self._last_index: int | None = None
        self._last_stamp_ns: int | None = None
        self._ahead: tuple[int, Future] | None = None  # (frame index, its frame being prepared)
        self._ahead_worker: ThreadPoolExecutor | None = None

    def prepare_ahead(self, message: codec.FrameMessage) -> None:
        """Start building the frame of ``message`` on a worker thread; ``handle`` of that message
        takes it (the same frame as built there: it depends on the images alone)."""
        if self._pipeline is None or (message.calibration, message.sensor) != self._camera:
            return  # the first frame builds the pipeline; a changed camera fails in handle
        if self._ahead_worker is None:
            self._ahead_worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="frame-ahead")
        frame = message.frame
        future = self._ahead_worker.submit(
            self._pipeline.prepare, frame.index, frame.stamp_ns, frame.left, right=frame.right, depth_m=frame.depth_m
        )
        self._ahead = (frame.index, future)

    def close(self) -> None:
        """Stop the worker thread of ``prepare_ahead``, if it was started."""
        if self._ahead_worker is not None:
            self._ahead_worker.shutdown(wait=True, cancel_futures=True)
            self._ahead_worker = None

    def _take_ahead(self, index: int) -> Any:
        """The frame prepared ahead for ``index`` (its errors raised here), or None."""
        ahead, self._ahead = self._ahead, None
        if ahead is None or ahead[0] != index:
            return None
        prepared = ahead[1].result()
        self.built_ahead += 1
        return prepared

    def refusal(self, message: codec.FrameMessage) -> str | None:
        """Why the frame cannot be tracked in this run, or None: another camera than the run's, or an
        index or stamp not after the last frame's (a repeated or stale message). ``serve`` drops such
        frames, counted in ``refused``; ``handle`` raises for another camera."""
        frame = message.frame
        if self._camera is not None and (message.calibration, message.sensor) != self._camera:
            return f"frame {frame.index} has another camera than the run's first frame; one run tracks one camera"
        if self._last_index is not None and (frame.index <= self._last_index or frame.stamp_ns <= self._last_stamp_ns):
            return f"frame {frame.index} (stamp {frame.stamp_ns} ns) is not after frame {self._last_index} (stamp {self._last_stamp_ns} ns)"
        return None

    def tracked_already(self, message: codec.FrameMessage) -> bool:
        """Whether the frame's index is not after the last frame's: it was sent before (or skipped)."""
        return self._last_index is not None and message.frame.index <= self._last_index

    def handle(self, message: codec.FrameMessage) -> FrontendMessages:
        """Track one frame; the pipeline is built on the first one, from its calibration and sensor."""
        camera = (message.calibration, message.sensor)
        if self._pipeline is None:
            logger.info("first frame: %s camera, %s", message.sensor, message.calibration.summary())
            log_cpu_times("at stream start")
            self._pipeline, self._camera = self._make_pipeline(*camera), camera
            self._map_sync = self._pipeline.map_sync
        elif camera != self._camera:
            raise CalibrationError(
                f"frame {message.frame.index} has camera {camera} but the run started with {self._camera}; "
                "one run tracks one camera: start a new run"
            )
        frame = message.frame
        if self._last_index is not None and frame.index > self._last_index + 1:
            self.skipped += frame.index - self._last_index - 1
        self._last_index, self._last_stamp_ns = frame.index, frame.stamp_ns
        started = time.perf_counter()
        out = self._pipeline.step(
            frame.index, frame.stamp_ns, frame.left, right=frame.right, depth_m=frame.depth_m,
            keyframes_in_flight=self.keyframes_in_flight, prepared=self._take_ahead(frame.index),
            candidates=self.candidates,
        )
        step_ms = (time.perf_counter() - started) * 1e3
        self.frames += 1
        if self.rerun is not None:
            self._unlogged = (message, out)  # logged by log_last_frame once its messages are out
        made = out.keyframes_made
        keyframe_bytes = tuple(codec.encode_keyframe(keyframe_message(kf, message.calibration, message.sensor)) for kf in made)
        self.keyframes += len(made)
        keyframe_id = int(out.keyframe.id) if out.keyframe is not None else -1
        pose_bytes = None
        if out.T_world_cam is not None:
            pose_bytes = codec.encode_pose_in_frame(codec.StampedPose(frame.stamp_ns, np.asarray(out.T_world_cam), "world"))
        state = codec.TrackingStateMessage(
            index=frame.index,
            stamp_ns=frame.stamp_ns,
            state=out.state,
            lost_reason=out.lost_reason,
            n_tracked=int(out.n_tracked),
            timings_ms=dict(out.timings_ms),
            has_pose=pose_bytes is not None,
            keyframe_id=keyframe_id,
            reference_keyframe_id=out.reference_keyframe_id if pose_bytes is not None else -1,
            T_reference_cam=out.T_reference_cam if pose_bytes is not None else None,
            relocalised=bool(out.relocalised),
        )
        made_ids = tuple(int(kf.id) for kf in made)
        return FrontendMessages(keyframe_bytes, pose_bytes, codec.encode_tracking_state(state), step_ms, keyframe_id, made_ids)

    @property
    def may_ask_backend(self) -> bool:
        """Whether tracking the next frame may ask the backend for relocalisation candidates: a
        lockstep frontend then applies every update first, so the backend answers from a map that
        does not depend on timing."""
        return self._pipeline is not None and self._pipeline.may_ask_backend

    @property
    def keyframes_in_flight(self) -> int:
        """Keyframes sent whose answer has not been applied (each keyframe gets one answer; a
        correction, such as a loop's, answers none). Without a backend's updates (``serve`` without
        ``backend``) this is 0: nothing to wait for. The last keyframe counts until its correction is
        applied when it was answered before its local BA (``local_ba_running``): the BA still runs.
        While the backend is gone (crashed, not restarted yet) it is 0 too: tracking makes keyframes
        as it needs them, on its own stereo or depth points, and they go to the restarted backend;
        held back they would leave tracking without points to track as the camera moves on."""
        if not self.tracks_backend or self.backend_gone:
            return 0
        return self.keyframes - self.answers_applied + int(self.local_ba_running)

    def log_last_frame(self) -> None:
        """Log the last handled frame to rerun: called after its messages are sent, so logging does
        not delay the pose, and before a map update changes the tracker's last frame."""
        if self._unlogged is not None:
            self._log_to_rerun(*self._unlogged)
            self._unlogged = None

    def _log_to_rerun(self, message: codec.FrameMessage, out: TrackingOutput) -> None:
        from zenslam.frontend.rerun_log import tracked_keypoints

        self.rerun.log_camera(message.calibration)
        self.rerun.log_frame(out, tracked_keypoints(self._pipeline, message.frame.index), message.frame.left)

    def apply_map_update(self, update: MapUpdate) -> None:
        """Apply the backend's correction to the pipeline's map before the next frame is tracked."""
        if self._map_sync is None:
            raise ZenslamError(
                f"a map update for keyframe {update.keyframe_id} arrived before any frame was tracked; "
                "is another frontend publishing keyframes in this session?"
            )
        self._map_sync.apply(update)
        self.updates_applied += 1
        self.answers_applied += int(update.answers_keyframe)


class _Outputs:
    """The frontend's publishers: everything it sends is lossless (poses, states and keyframes must arrive)."""

    def __init__(self, session: bus.Session, session_name: str):
        self.pose = bus.declare_publisher(session, keys.frontend_pose(session_name), codec.POSE_IN_FRAME, "lossless")
        self.state = bus.declare_publisher(session, keys.frontend_state(session_name), codec.TRACKING_STATE, "lossless")
        self.keyframe = bus.declare_publisher(session, keys.frontend_keyframe(session_name), codec.KEYFRAME, "lossless")
        self.status = bus.declare_publisher(session, keys.status(session_name, STAGE), codec.STAGE_STATUS, "lossless")
        self._last_state: bytes | None = None

    def send(self, messages: FrontendMessages, keyframes: bool = True) -> None:
        """The frame's messages; its keyframes only when ``keyframes`` (held while the backend is gone)."""
        for keyframe in messages.keyframes if keyframes else ():
            self.keyframe.put(keyframe)
        if messages.pose is not None:
            self.pose.put(messages.pose)
        self.state.put(messages.state)
        self._last_state = messages.state

    def send_last_state_again(self) -> None:
        """The newest frame's state once more (nothing before the first frame is tracked)."""
        if self._last_state is not None:
            self.state.put(self._last_state)

    def send_status(self, status: codec.StageStatusMessage) -> None:
        self.status.put(codec.encode_stage_status(status))

    def end_streams(self, frames: int, keyframes: int) -> None:
        self.keyframe.put(codec.encode_end_of_stream(codec.KEYFRAME, keyframes))
        self.state.put(codec.encode_end_of_stream(codec.TRACKING_STATE, frames))


class RelocalisationQueries:
    """Asks the backend for relocalisation candidates on backend/relocalisation (the tracker's
    ``CandidateSource``); None, with a warning, when no answer comes within ``timeout_s`` seconds."""

    def __init__(self, session: bus.Session, session_name: str, timeout_s: float) -> None:
        self._session = session
        self._key = keys.backend_relocalisation_query(session_name)
        self._timeout_s = timeout_s
        self._encoding = bus.Encoding.APPLICATION_PROTOBUF.with_schema(codec.RELOCALISATION_QUERY)
        self.asked = 0  # queries sent
        self.unanswered = 0  # queries without an answer

    def __call__(self, query: RelocalisationQuery) -> RelocalisationCandidates | None:
        self.asked += 1
        payload = codec.encode_relocalisation_query(query)
        for reply in self._session.get(self._key, payload=payload, encoding=self._encoding, timeout=self._timeout_s):
            if reply.ok is not None:
                return codec.decode_relocalisation_candidates(reply.ok.payload.to_bytes())
            logger.warning("the backend refused a relocalisation query: %s", reply.err.payload.to_string())
        self.unanswered += 1
        logger.warning(
            "no relocalisation candidates from the backend within %.1f s (frontend.relocalisation_timeout_s); "
            "the frame stays lost", self._timeout_s,
        )  # fmt: skip
        return None


def serve(
    session: bus.Session,
    session_name: str,
    node: FrontendNode,
    mode: RunMode,
    bus_config: bus.BusConfig,
    should_stop: Callable[[], bool],
    map_updates: FrontendConfig | None = None,
) -> bool:
    """Receive frames until end of stream (True) or ``should_stop()`` (False); the streams are ended either way.

    With ``map_updates`` (the config of the map-update inbox) the backend's map updates are applied
    (see the module doc); without it the frontend tracks on its own map.
    """
    outputs = _Outputs(session, session_name)
    updates = MapUpdateInbox(session, session_name, map_updates, outputs.keyframe.put) if map_updates is not None else None
    node.tracks_backend = updates is not None
    if map_updates is not None:
        node.candidates = RelocalisationQueries(session, session_name, map_updates.relocalisation_timeout_s)
    # Lockstep waits for each keyframe's update; live and pipelined apply the updates that have arrived.
    wait_for_updates = updates is not None and mode == "lockstep"
    if mode != "live":
        # Lockstep and pipelined: every frame, in order; the source waits for our state before sending more.
        frames = bus.subscribe(session, keys.sensor_frame(session_name), codec.decode_sensor_frame, "lossless", bus_config.lossless_queue)
    else:
        # Live: keep the newest frames and drop the oldest, as a tracker must keep up with its camera.
        frames = bus.subscribe(session, keys.sensor_frame(session_name), codec.decode_sensor_frame, "live", bus_config.live_queue)
    outputs.send_status(codec.StageStatusMessage(STAGE, "starting"))
    warm_up_kernels()  # before the stage is alive: no frame waits for numba's compile or cache load
    ended = False
    try:
        with bus.declare_alive(session, session_name, STAGE):
            while not should_stop():
                message = frames.get(timeout_s=0.1)
                if updates is not None:
                    node.backend_gone = updates.backend_gone()
                if updates is not None and not wait_for_updates:
                    updates.apply_pending(node)
                if updates is not None and updates.ended:
                    # The backend ends its stream before ours only when it was stopped: no more map
                    # updates will come (lockstep would wait for one forever), so the run ends here.
                    logger.warning("the backend ended its stream: ending ours after %d frames", node.frames)
                    break
                if message is None:
                    continue
                if isinstance(message, codec.EndOfStream):
                    logger.info("end of stream after %d frames from the source (%d tracked)", message.count, node.frames)
                    if frames.rejected or node.refused:
                        logger.warning("dropped %d frame message(s) that did not decode and refused %d", frames.rejected, node.refused)
                    if wait_for_updates:
                        logger.info("%d of %d frames built while waiting for the backend's map update", node.built_ahead, node.frames)
                        updates.apply_due(node, node.frames, True, should_stop)
                    if updates is not None:
                        updates.wait_for_a_restarted_backend(bus_config.start_timeout_s, should_stop)
                    ended = True
                    break
                if (problem := node.refusal(message)) is not None:
                    node.refused += 1
                    logger.warning("refused a frame (%d so far): %s", node.refused, problem)
                    if node.tracked_already(message):
                        # Sent again by a restarted source, or to this restarted frontend: the source
                        # waits for an answer, and the newest state (of a later frame) is one.
                        outputs.send_last_state_again()
                    continue
                if wait_for_updates:
                    # Lockstep: the updates due before this frame (all of them before a frame that
                    # may ask the backend where it is), applied while this frame is built.
                    drain = node.may_ask_backend
                    if updates.waits_before(node.frames, drain):
                        node.prepare_ahead(message)
                        updates.apply_due(node, node.frames, drain, should_stop)
                        if updates.ended:
                            continue  # the backend was stopped while we waited: the run ends above
                # ORB-SLAM's tracking runs beside local mapping: while the BA of an answered
                # keyframe runs, local mapping is not idle to the keyframe decision.
                node.local_ba_running = wait_for_updates and updates.due > 0
                try:
                    sent = node.handle(message)
                except Exception as exc:
                    outputs.send_status(codec.StageStatusMessage(STAGE, "failed", node.frames, detail=f"{type(exc).__name__}: {exc}"))
                    raise
                # Keyframes made while the backend is gone wait, in order, for its restart.
                outputs.send(sent, keyframes=not node.backend_gone)
                if updates is not None:
                    updates.sent(sent)
                node.log_last_frame()
                if wait_for_updates:
                    updates.schedule(sent, node.frames)
                status = codec.StageStatusMessage(STAGE, "running", node.frames, sent.step_ms, frames.depth, node.skipped)
                outputs.send_status(status)
                logger.debug("frame %d: %.1f ms, queue %d", message.frame.index, sent.step_ms, status.queue_depth)
    finally:
        node.close()
        outputs.end_streams(node.frames, node.keyframes_before + node.keyframes)
        outputs.send_status(
            codec.StageStatusMessage(STAGE, "finished", node.frames, dropped=node.skipped, detail="" if ended else STOPPED)
        )
        frames.close()
        if updates is not None:
            updates.close()
    return ended


def default_pipeline_factory(frontend_config: Any, vocabulary: Any = None) -> PipelineFactory:
    """Builds the real tracker, FrontendPipeline(config, calibration, sensor, vocabulary)."""
    from zenslam.frontend.pipeline import FrontendPipeline

    def make(calibration: PinholeCalibration, sensor: SensorKind) -> Pipeline:
        return FrontendPipeline(frontend_config, calibration, sensor, vocabulary)

    return make


def continuing_config(session: bus.Session, session_name: str, config: FrontendConfig, timeout_s: float) -> tuple[FrontendConfig, int]:
    """A restarted frontend's configuration, and the keyframes the backend has processed: it enters
    the backend's map by relocalising, as a run from a saved map does, with keyframe and point ids
    past every id the backend knows (its backend/trajectory reply names them)."""
    from zenslam.runtime.backend_queries import query_trajectory

    trajectory = query_trajectory(session, session_name, timeout_s)
    if trajectory is None:
        raise bus.BusError(f"restarted: no answer from the backend to backend/trajectory within {timeout_s:.0f} s; the map cannot be entered")
    entering = entering_map(config, trajectory.next_keyframe_id, trajectory.next_frontend_point_id)
    return entering, int(trajectory.keyframes_processed)


def load_relocalisation_vocabulary(config: FrontendConfig) -> Any:
    """The vocabulary of ``frontend.vocabulary``, or None when relocalisation is off; a missing or bad
    file is a VocabularyError naming it. The shipped one (an empty setting) is loaded at its first use
    (``ShippedVocabularyOnDemand``): a run that never loses track never holds it."""
    if not config.tracking.relocalisation.enabled:
        return None
    if not config.vocabulary:
        from zenslam.vocabulary.on_demand import ShippedVocabularyOnDemand

        return ShippedVocabularyOnDemand()
    from zenslam.vocabulary import load_vocabulary

    return load_vocabulary(config.vocabulary)


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``python -m zenslam.frontend.node --session S [--config FILE] [--connect EP] ...``."""
    return run_stage(STAGE, __doc__, _run, argv, _add_arguments)


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--map-updates", action="store_true",
        help="apply the backend's map updates (lockstep: wait for the update of each keyframe before the next frame)",
    )
    add_wait_for_argument(parser, "the frontend starts")


def _run(stage: StageStart) -> None:
    """The frontend process: its vocabulary loaded, then its node served on the run's session."""
    if stage.stopped_before_joining():  # a stop held while the modules above were imported
        return
    args = stage.args
    config = stage.section(STAGE, FrontendConfig)
    import cv2

    # OpenCV's thread pool costs more than it saves on the small calls here; the extractor runs left/right
    # on its own threads.
    cv2.setNumThreads(1)
    # Relocalisation asks the backend: without its map updates there is no backend to ask.
    vocabulary = load_relocalisation_vocabulary(config) if args.map_updates else None
    if args.restart and vocabulary is None:
        raise ZenslamError(
            "a restarted frontend enters the backend's map by relocalising: it needs the backend (--map-updates) "
            "and frontend.tracking.relocalisation.enabled"
        )
    if stage.stopped_before_joining():
        return

    from zenslam.frontend.rerun_log import FrontendLog

    with stage.rerun_recording() as recording, stage.open_session() as session:
        stage.require_alive(session, args.wait_for)
        keyframes_before = 0
        if args.restart:
            config, keyframes_before = continuing_config(session, args.session, config, stage.bus_config.start_timeout_s)
            logger.info(
                "restart %d: entering the backend's map (%d keyframes processed) by relocalising; keyframe ids from "
                "%d, point ids from %d", args.restart, keyframes_before, config.tracking.local_map.keyframe_id_start,
                config.tracking.local_map.point_id_start,
            )  # fmt: skip
        node = FrontendNode(default_pipeline_factory(config, vocabulary))
        node.keyframes_before = keyframes_before
        node.rerun = FrontendLog(recording) if recording is not None else None
        map_updates = config if args.map_updates else None
        serve(session, args.session, node, stage.mode(), stage.bus_config, stage.stop, map_updates=map_updates)


if __name__ == "__main__":
    sys.exit(main())
