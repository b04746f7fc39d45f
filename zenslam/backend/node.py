"""The backend process: frontend/keyframe in, local mapping, backend/map_update out; answers backend/map,
backend/trajectory and backend/relocalisation.

``BackendNode.step`` runs local mapping, then loop closing, on one decoded keyframe and returns the
map updates to publish (the keyframe's answer, then any loop correction) and the verified loop
candidates for backend/loop; it is testable without the bus. With ``answer_before_local_ba`` the
worker runs it on a stereo or RGB-D keyframe in two halves, ``begin`` (up to fusion: the answer,
published at once) and ``finish`` (local BA, keyframe culling and loop closing: the corrections),
so that a lockstep frontend tracks its next frame while local BA runs. A background global BA's
correction is published between keyframes when it finishes. ``serve`` is the loop: it takes
keyframes from a lossless, bounded inbox (a full inbox blocks the frontend's send, nothing is
dropped), tells local mapping how many keyframes wait behind the current one (ORB-SLAM's
CheckNewKeyFrames: a backlog defers fusion, local BA and keyframe culling to the last queued
keyframe; the end-of-stream marker does not count, so the last keyframe always gets them),
publishes each keyframe's updates and a backend/status with the step time, the per-step timings
and the queue depth, and answers the queryables between steps, on the same thread, so a reply
always shows the map between two keyframes. After the frontend's end of stream it forwards the end
of stream on backend/map_update and keeps answering queries for ``BackendConfig.linger_s`` seconds
or until stopped.

With ``backend.map_file`` the node starts from a saved map (``map_file``: its keyframe database
answers relocalisation queries at once); with ``backend.save_map`` it writes its map when its
input ends (or it is stopped), before it ends its own stream.

The inbox (``keyframe_inbox``), the publishers (``outputs``), the queryables (``queryables``) and
the rebuild from the journal (``journal_rebuild``) are modules of their own; this one holds the
map's owner and the loop that drives it.
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from zenslam.backend.config import BackendConfig
from zenslam.backend.journal import JOURNAL_NAME, JournalWriter
from zenslam.backend.journal_rebuild import journal_entries, rebuild_from_journal
from zenslam.backend.kernel_warm_up import warm_up_kernels
from zenslam.backend.keyframe_inbox import (
    Received,
    count_keyframes_waiting,
    keyframes_waiting,
    newer_keyframes_waiting,
    subscribe_keyframes,
)
from zenslam.backend.local_mapping import LocalMapper, bundle_adjuster, map_update_from_changes, new_backend_map
from zenslam.backend.loop_messages import loop_messages
from zenslam.backend.keyframe_database import KeyframeDatabase
from zenslam.backend.map import BackendMap
from zenslam.backend.outputs import STAGE, BackendOutputs, StepOutput
from zenslam.backend.queryables import BackendQueryables
from zenslam.backend.relocalisation_candidates import relocalisation_reply
from zenslam.errors import ZenslamError
from zenslam.runtime import bus
from zenslam.runtime.stage import STOPPED, StageStart, add_wait_for_argument, log_cpu_times, run_stage, yield_cpu
from zenslam.schemas import codec
from zenslam.schemas.map_update import MapUpdate
from zenslam.schemas.relocalisation import RelocalisationCandidates, RelocalisationQuery

if TYPE_CHECKING:
    from zenslam.backend.global_ba_runner import GlobalBARunner
    from zenslam.backend.map_file import MapHeader
    from zenslam.backend.loop_closing import LoopCloser
    from zenslam.backend.place_recognition import PlaceRecognition
    from zenslam.backend.rerun_log import BackendLog

logger = logging.getLogger(__name__)

_POLL_S = 0.02  # seconds the loop waits for a keyframe before answering queries again


class BackendNode:
    """The owner of the backend map: local mapping and loop closing on decoded keyframes, and the map
    and trajectory replies; no transport in here."""

    def __init__(
        self,
        mapper: LocalMapper,
        places: PlaceRecognition | None = None,
        loop_closer: LoopCloser | None = None,
        global_ba: GlobalBARunner | None = None,
        rerun: BackendLog | None = None,
    ) -> None:
        self.mapper = mapper
        self.map: BackendMap = mapper.map  # the node's map, lent to local mapping and loop closing
        self.places = places  # the keyframe database (None: no vocabulary, no place recognition)
        self.loop_closer = loop_closer  # None: loop closing off
        self.global_ba = global_ba  # None: no global BA after a loop
        self._newest: tuple[int, int] = (-1, 0)  # id and stamp of the newest keyframe processed
        self.rerun = rerun  # logs the map, graphs and timings after each keyframe to the stage's .rrd
        self.processed = 0  # keyframes processed
        self.finished = False  # the input's end of stream has been processed
        self.loaded: MapHeader | None = None  # the header of the saved map the node started from, if any
        self.refused = 0  # keyframes refused (see ``refusal``)
        self._camera: tuple | None = None  # calibration, sensor and pyramid scales of the first keyframe
        self._begun: codec.KeyframeMessage | None = None  # the keyframe ``begin`` took, for ``finish``
        self.answer_before_local_ba = False  # the worker publishes each answer before local BA (begin/finish)

    @classmethod
    def from_config(cls, config: BackendConfig, global_ba_in_background: bool = False) -> BackendNode:
        """The node with the real local mapper, gtsam local bundle adjuster and, when enabled, loop
        closer and global BA (in a helper process when ``global_ba_in_background``: pipelined and
        live runs; in place in lockstep, so its result lands at a deterministic point)."""
        from zenslam.backend.place_recognition import PlaceRecognition
        from zenslam.vocabulary import load_vocabulary

        bmap = new_backend_map(config.local_mapping)
        places = PlaceRecognition(load_vocabulary(config.vocabulary or None))
        mapper = LocalMapper(bmap, config.local_mapping, bundle_adjuster(config.local_ba), places.feature_nodes)
        loaded = None
        if config.map_file:
            from zenslam.backend.map_file import load_map

            loaded = load_map(config.map_file, bmap, places)
        loop_closer, global_ba = None, None
        if config.loop_closing.enabled:
            from zenslam.backend.global_ba_runner import GlobalBARunner
            from zenslam.backend.loop_closing import LoopCloser

            loop_closer = LoopCloser(bmap, places, config.loop_closing)
            if config.loop_closing.global_ba.enabled:
                global_ba = GlobalBARunner(bmap, config.loop_closing.global_ba, config.local_mapping.ba_window, global_ba_in_background)
        node = cls(mapper, places, loop_closer, global_ba)
        node.loaded = loaded
        node.answer_before_local_ba = config.answer_before_local_ba
        return node

    def step(self, keyframe: codec.KeyframeMessage, queued: int = 0) -> StepOutput:
        """Insert one keyframe, run local mapping, then loop closing on it.

        ``queued``: keyframes waiting behind this one (0 in lockstep); see ``LocalMapper.process``.
        The answer says how many corrections follow it, so a lockstep frontend applies them before
        its next frame. With ``answer_before_local_ba`` it is ``begin`` then ``finish``: the same
        map, in the updates the worker publishes (a replay or a rebuild from the journal sends
        the same messages as the run did).
        """
        if self.answers_before_local_ba(keyframe):
            answer, rest = self.begin(keyframe, queued), self.finish()
            return StepOutput([*answer.updates, *rest.updates], rest.loops)
        self._check_first(keyframe)
        update = self.mapper.process(keyframe, queued=queued)
        self._took(keyframe)
        corrections, loops = self._after_local_mapping(keyframe, update)
        answer = dataclasses.replace(update, corrections_following=len(corrections))
        return StepOutput([answer, *corrections], loops)

    def answers_before_local_ba(self, keyframe: codec.KeyframeMessage) -> bool:
        """Whether ``keyframe`` is answered before its local BA (``begin`` then ``finish``): with
        ``answer_before_local_ba``, a stereo or RGB-D one. A monocular keyframe is answered after its
        BA: beside a busy local mapping ORB-SLAM's monocular tracking makes no keyframe, and a
        monocular map starved of keyframes goes wrong (benchmarks/local_mapping.md)."""
        return self.answer_before_local_ba and keyframe.sensor != "mono"

    def begin(self, keyframe: codec.KeyframeMessage, queued: int = 0) -> StepOutput:
        """``step`` in two halves (``backend.answer_before_local_ba``): insertion, point culling,
        triangulation and fusion, and the keyframe's answer, to publish at once; ``finish`` must
        follow before the next keyframe. The answer announces one update after it, the keyframe's
        local-mapping correction (which announces the loop corrections after it), and that a
        lockstep frontend may track its next frame before applying them."""
        self._check_first(keyframe)
        answer = self.mapper.begin(keyframe, queued=queued)
        self._took(keyframe)
        self._begun = keyframe
        return StepOutput([dataclasses.replace(answer, corrections_following=1, corrections_after_next_frame=True)])

    def finish(self) -> StepOutput:
        """The second half of ``step`` on the keyframe ``begin`` took: local BA, keyframe culling and
        loop closing; its local-mapping correction, then the loop corrections it announces."""
        keyframe, self._begun = self._begun, None
        if keyframe is None:
            raise RuntimeError("BackendNode.finish without a keyframe begun")
        refined = self.mapper.finish()
        corrections, loops = self._after_local_mapping(keyframe, refined)
        return StepOutput([dataclasses.replace(refined, corrections_following=len(corrections)), *corrections], loops)

    def _check_first(self, keyframe: codec.KeyframeMessage) -> None:
        """Note the run's camera on its first keyframe; a saved map must have been made with it."""
        if self._camera is None:
            self._camera = (keyframe.calibration, keyframe.sensor, keyframe.scale_factors.tobytes())
        if self.loaded is not None and self.processed == 0:
            from zenslam.backend.map_file import check_compatible

            vocabulary = self.places.vocabulary if self.places is not None else None
            check_compatible(
                self.loaded, keyframe.calibration, keyframe.sensor,
                vocabulary.content_id if vocabulary is not None else self.loaded.vocabulary_id,
            )  # fmt: skip

    def _took(self, keyframe: codec.KeyframeMessage) -> None:
        self.processed += 1
        self._newest = (int(keyframe.id), int(keyframe.stamp_ns))

    def _after_local_mapping(
        self, keyframe: codec.KeyframeMessage, update: MapUpdate
    ) -> tuple[list[MapUpdate], list[codec.LoopMessage]]:
        """The keyframe database follows the map (``update`` removed keyframes), then loop closing
        on the keyframe: its corrections and loop messages."""
        kf_id = int(keyframe.id)
        corrections: list[MapUpdate] = []
        loops: list[codec.LoopMessage] = []
        if self.places is not None:
            self.places.remove(np.asarray(update.removed_keyframe_ids).tolist())
            if kf_id in self.map.keyframes:
                self.places.add(kf_id, self.map.keyframe(kf_id).descriptors)
        if self.loop_closer is not None and kf_id in self.map.keyframes:
            corrections, loops = self._close_loops(kf_id, update)
        if self.rerun is not None:
            self.rerun.log_keyframe(keyframe, self.map, self.mapper.last_ba_stats, self.mapper.last_timings_ms)
        return corrections, loops

    def refusal(self, keyframe: codec.KeyframeMessage) -> str | None:
        """Why ``keyframe`` cannot be mapped, or None: what the decoder could not know (its values are
        checked there). A refused keyframe changes nothing; ``refuse`` counts and answers it."""
        kf_id = int(keyframe.id)
        if not self._is_new(kf_id):
            return f"keyframe {kf_id} is not newer than keyframe {self._newest[0]}, the newest mapped; keyframe ids increase"
        if self._camera is not None and self._camera != (keyframe.calibration, keyframe.sensor, keyframe.scale_factors.tobytes()):
            return f"keyframe {kf_id} has another camera or pyramid than the run's first keyframe"
        points = self.map.points
        if any(point_id in points for point_id in keyframe.new_point_ids.tolist()):
            return f"keyframe {kf_id} brings new points whose ids are already in the map"
        return None

    def refuse(self, keyframe: codec.KeyframeMessage) -> StepOutput:
        """Count a refused keyframe. A keyframe with a new id is answered with no change, so that a
        lockstep frontend waiting for that answer goes on; a repeated id gets no second answer."""
        self.refused += 1
        kf_id = int(keyframe.id)
        if not self._is_new(kf_id):
            return StepOutput([])
        return StepOutput([MapUpdate(keyframe_id=kf_id, stamp_ns=int(keyframe.stamp_ns))])

    @property
    def newest_id(self) -> int:
        """The id of the newest keyframe processed (-1: none)."""
        return self._newest[0]

    def _is_new(self, kf_id: int) -> bool:
        """Whether keyframe ``kf_id`` comes after every keyframe mapped (the frontend's ids increase)."""
        return kf_id > self._newest[0] and kf_id not in self.map.keyframes

    def _close_loops(self, kf_id: int, update: MapUpdate) -> tuple[list[MapUpdate], list[codec.LoopMessage]]:
        T_before = self.map.keyframe(kf_id).T_world_cam.copy()
        started = time.perf_counter()
        outcome = self.loop_closer.process(kf_id)
        self.mapper.last_timings_ms["loop_closing"] = (time.perf_counter() - started) * 1e3
        loops = loop_messages(self.map, outcome, T_before)
        if not outcome.accepted:
            return [], loops
        if self.global_ba is not None:
            started = time.perf_counter()
            if self.global_ba.start():
                self.mapper.last_timings_ms["global_ba"] = (time.perf_counter() - started) * 1e3
        correction = map_update_from_changes(self.map, kf_id, update.stamp_ns, self.map.take_changes(), kind="correction")
        return [correction], loops

    def poll_global_ba(self) -> MapUpdate | None:
        """The correction of a background global BA that has finished (applied to the map now), or None."""
        if self.global_ba is None or not self.global_ba.poll():
            return None
        kf_id, stamp_ns = self._newest
        return map_update_from_changes(self.map, kf_id, stamp_ns, self.map.take_changes(), kind="correction")

    def finish_global_ba(self) -> MapUpdate | None:
        """Wait for a background global BA still running and return its correction (None if none ran)."""
        if self.global_ba is None or not self.global_ba.wait():
            return None
        kf_id, stamp_ns = self._newest
        return map_update_from_changes(self.map, kf_id, stamp_ns, self.map.take_changes(), kind="correction")

    def global_ba_before_save(self) -> MapUpdate | None:
        """A global BA over the whole map, in place, before the map is saved; its correction, or None
        (no global BA configured, no keyframe mapped in this run, or nothing to optimise).

        ORB-SLAM's maps get a global BA only after a closed loop. A map saved for localisation is
        all that later runs will track against, and local BA alone leaves far points where few
        windows could move them; a global BA over the whole map moves them where every keyframe
        that sees them agrees (benchmarks/saved_maps.md)."""
        kf_id, stamp_ns = self._newest
        if kf_id < 0 or self.global_ba is None or not self.global_ba.run_in_place():
            return None  # kf_id < 0: no keyframe mapped in this run, the map is the one it loaded
        return map_update_from_changes(self.map, kf_id, stamp_ns, self.map.take_changes(), kind="correction")

    def save_map(self, path: str) -> None:
        """Write the map with its keyframes' bags of words to ``path`` (format: ``backend.map_file``)."""
        from zenslam import __version__
        from zenslam.backend.map_file import save_map

        if self.places is None:
            raise ZenslamError(f"the map cannot be saved to {path} without a vocabulary: its keyframes have no bags of words")
        save_map(path, self.map, self.places, __version__)

    def close(self) -> None:
        """Stop the global BA helper process, if any."""
        if self.global_ba is not None:
            self.global_ba.close()

    @property
    def last_timings_ms(self) -> dict[str, float]:
        """Milliseconds per local-mapping step of the last keyframe ("total" is the whole step)."""
        return dict(self.mapper.last_timings_ms)

    def trajectory(self, waiting: Sequence[codec.KeyframeMessage] = ()) -> codec.KeyframeTrajectoryMessage:
        """The poses (T_world_cam) of the keyframes in the map now, in insertion order, and of the
        culled ones, each where its parent is now; and the first ids a restarted frontend may use,
        past the map's and those of the keyframes ``waiting`` in the inbox."""
        kfs = list(self.map.keyframes.values())
        culled_ids, culled_stamps, culled_T = self.map.culled.poses({kf.id: kf.T_world_cam for kf in kfs})
        next_ids = self.map.next_ids()
        next_keyframe_id = max([next_ids["keyframe"], self.newest_id + 1, *(int(kf.id) + 1 for kf in waiting)])
        next_point_id = max([next_ids["frontend_point"], *(int(kf.new_point_ids.max()) + 1 for kf in waiting if len(kf.new_point_ids))])
        return codec.KeyframeTrajectoryMessage(
            keyframe_ids=np.array([kf.id for kf in kfs], dtype=np.int64),
            stamps_ns=np.array([kf.stamp_ns for kf in kfs], dtype=np.int64),
            T_world_cam=np.array([kf.T_world_cam for kf in kfs], dtype=float).reshape(-1, 4, 4),
            keyframes_processed=self.processed,
            finished=self.finished,
            culled_keyframe_ids=culled_ids,
            culled_stamps_ns=culled_stamps,
            culled_T_world_cam=culled_T,
            next_keyframe_id=next_keyframe_id,
            next_frontend_point_id=next_point_id,
        )

    def relocalisation_candidates(self, query: RelocalisationQuery) -> RelocalisationCandidates:
        """Candidate places of the whole map for a lost frame's bag of words, best first, with the
        keyframes and points the frontend needs to match them (``relocalisation_reply``)."""
        if self.places is None:  # no vocabulary: no place is ever recognised
            return relocalisation_reply(self.map, KeyframeDatabase(), lambda a, b: 0.0, query, self.processed)
        return relocalisation_reply(self.map, self.places.database, self.places.score, query, self.processed)

    def snapshot(self) -> codec.MapSnapshotMessage:
        """The keyframe poses and the map points (ids ascending, positions in metres, world frame)."""
        points = self.map.points
        ids = sorted(points)
        return codec.MapSnapshotMessage(
            keyframes=self.trajectory(),
            point_ids=np.array(ids, dtype=np.int64),
            p_world=np.array([points[p].p_world for p in ids], dtype=float).reshape(-1, 3),
        )


def serve(
    session: bus.Session,
    session_name: str,
    node: BackendNode,
    config: BackendConfig,
    should_stop: Callable[[], bool],
    journal: Path | None = None,
    rebuild: bool = False,
    lockstep: bool = False,
) -> bool:
    """Process keyframes until the end of stream (True) or ``should_stop()`` (False); the map-update
    stream is ended either way. After the end of stream, answer queries until ``config.linger_s``
    seconds have passed or ``should_stop()``. ``lockstep``: keyframes waiting in the inbox never
    defer local mapping (``LocalMapper.process``), so the map does not depend on timing.

    ``journal``: the file every accepted keyframe is appended to before it is mapped (``journal``
    module); with ``rebuild`` (a restarted backend) the map is first rebuilt from it, and the answers
    it lacks are published. Keyframes arriving meanwhile wait in the inbox, which is subscribed
    before the liveliness token appears: a frontend that resends its unanswered keyframes when the
    token comes back loses none (one already journaled is a repeated id, refused without an answer).
    """
    outputs = BackendOutputs(session, session_name)
    inbox = subscribe_keyframes(session, session_name, config.keyframe_queue)
    queryables = BackendQueryables(session, session_name)
    outputs.send_status(codec.StageStatusMessage(STAGE, "starting"))
    entries = journal_entries(journal) if rebuild and journal is not None else []
    writer = JournalWriter(journal) if journal is not None else None
    ended = False
    try:
        with bus.declare_alive(session, session_name, STAGE):
            rebuilt_upto = rebuild_from_journal(outputs, node, entries, writer, should_stop) if rebuild else None
            ended = _process(outputs, inbox, queryables, node, should_stop, writer, rebuilt_upto, lockstep)
            _save_map(outputs, node, config, finish_global_ba=ended, journal=writer)  # stopped: the map as far as it got
            if ended:
                _end_stream(outputs, node)
                _linger(queryables, node, config.linger_s, should_stop)
    finally:
        if not ended:
            left = count_keyframes_waiting(inbox)
            if left:
                logger.warning("stopped with at least %d keyframe(s) not processed (%d processed)", left, node.processed)
            _end_stream(outputs, node, STOPPED)
        inbox.close()
        queryables.close()
        if writer is not None:
            writer.close()
    return ended


def _process(
    outputs: BackendOutputs, inbox: bus.Inbox[Received], queryables: BackendQueryables, node: BackendNode, should_stop,
    journal: JournalWriter | None = None, rebuilt_upto: int | None = None, lockstep: bool = False,
) -> bool:
    """The worker loop: answer queries, take a keyframe, map it, publish; True at the end of stream.
    ``rebuilt_upto``: a restarted backend's newest keyframe from the journal; the frontend sends its
    unanswered keyframes again when it sees the restart, and those up to this one are already mapped."""
    while not should_stop():
        queryables.answer(node, lambda: keyframes_waiting(inbox))
        if (correction := node.poll_global_ba()) is not None:
            outputs.update.put(codec.encode_map_update(correction))
            if journal is not None:
                journal.global_ba_applied()
        received = inbox.get(timeout_s=_POLL_S)
        if received is None:
            continue
        payload, message = received
        if isinstance(message, codec.EndOfStream):
            if message.count != node.processed:
                logger.warning("the frontend sent %d keyframes but %d were processed", message.count, node.processed)
            totals = node.mapper.totals
            logger.info(
                "end of stream: %d keyframes processed; local mapping deferred fusion and BA on %d (keyframes "
                "queued behind them), placing %d on the map", node.processed, totals["deferred"], totals["placed"],
            )  # fmt: skip
            if inbox.rejected or node.refused:
                logger.warning("dropped %d keyframe message(s) that did not decode and refused %d", inbox.rejected, node.refused)
            return True
        if node.processed == 0:
            log_cpu_times("at stream start")
        started = time.perf_counter()
        # Lockstep never defers local mapping: a backlog there depends on timing (a frontend with
        # frontend.lockstep_lag_frames > 1 sends keyframes while one is mapped).
        queued = 0 if lockstep else newer_keyframes_waiting(inbox, int(message.id))
        if rebuilt_upto is not None and message.id <= rebuilt_upto:
            logger.info("keyframe %d sent again after the restart: mapped from the journal already", message.id)
            continue
        if (problem := node.refusal(message)) is not None:
            outputs.send_step(node.refuse(message))
            logger.warning("refused a keyframe (%d so far): %s", node.refused, problem)
            continue
        if journal is not None:
            journal.keyframe(payload, queued)
        try:
            if node.answers_before_local_ba(message):
                # The answer goes out before local BA: the frontend tracks its next frame meanwhile.
                outputs.send_step(node.begin(message, queued))
                output = node.finish()
            else:
                output = node.step(message, queued)
        except Exception as exc:
            outputs.send_status(codec.StageStatusMessage(STAGE, "failed", node.processed, detail=f"{type(exc).__name__}: {exc}"))
            raise
        outputs.send_step(output)
        if journal is not None:
            journal.answered(int(message.id))
        step_ms = (time.perf_counter() - started) * 1e3
        depth = inbox.depth
        if node.rerun is not None:
            node.rerun.log_queue_depth(message, depth)
        timings = node.last_timings_ms
        outputs.send_status(codec.StageStatusMessage(STAGE, "running", node.processed, step_ms, depth, timings_ms=timings))
        logger.debug("keyframe %d: %.1f ms (local BA %.1f ms), queue %d", message.id, step_ms, timings.get("local_ba", 0.0), depth)
    return False


def _save_map(
    outputs: BackendOutputs, node: BackendNode, config: BackendConfig, finish_global_ba: bool, journal: JournalWriter | None = None
) -> None:
    """With ``backend.save_map``: the map (after a global BA still running and, with
    ``backend.global_ba_before_save``, one more over the final map, when ``finish_global_ba``; a
    stopped backend does neither), written before the stream ends, so whoever waits for the end of
    stream finds the file complete. A map without keyframes is not written."""
    if not config.save_map:
        return
    if not node.map.keyframes:
        logger.warning("no keyframe was mapped: no map written to %s", config.save_map)
        return
    if finish_global_ba and (correction := node.finish_global_ba()) is not None:
        outputs.update.put(codec.encode_map_update(correction))
        if journal is not None:
            journal.global_ba_applied()
    if finish_global_ba and config.global_ba_before_save and (correction := node.global_ba_before_save()) is not None:
        outputs.update.put(codec.encode_map_update(correction))  # after the last keyframe: no journal entry needed
    node.save_map(config.save_map)


def _end_stream(outputs: BackendOutputs, node: BackendNode, detail: str = "") -> None:
    node.finished = True
    outputs.update.put(codec.encode_end_of_stream(codec.MAP_UPDATE, node.processed))
    outputs.send_status(codec.StageStatusMessage(STAGE, "finished", node.processed, detail=detail))


def _linger(queryables: BackendQueryables, node: BackendNode, linger_s: float, should_stop: Callable[[], bool]) -> None:
    deadline = time.monotonic() + linger_s
    while time.monotonic() < deadline and not should_stop():
        queryables.answer(node)
        time.sleep(_POLL_S)


def main(argv: list[str] | None = None) -> int:
    """Entry point: ``python -m zenslam.backend.node --session S [--config FILE] [--connect EP] ...``."""
    return run_stage(STAGE, __doc__, _run, argv, lambda parser: add_wait_for_argument(parser, "the backend starts"))


def _run(stage: StageStart) -> None:
    """The backend process: its node built from its section, then served on the run's session."""
    if stage.stopped_before_joining():  # a stop held while the modules above were imported
        return
    args = stage.args
    config = stage.section(STAGE, BackendConfig)
    mode = stage.mode()
    lockstep = mode == "lockstep"
    yield_cpu(config.nice if mode == "live" else 0)  # only a live camera does not wait for tracking
    node = BackendNode.from_config(config, global_ba_in_background=not lockstep)
    mapping = config.local_mapping
    warm_up_kernels(config)  # before the first keyframe, as the frontend's are
    if not lockstep and mapping.defer_when_queued and mapping.placement.enabled:
        # A keyframe is placed by pose optimisation when others wait behind it: then the backend is
        # behind, and must not also wait for numba's start and the kernel's load (~1 s, ~60-100 MB).
        from zenslam.pose_optimizer import load_compiled_kernel

        load_compiled_kernel()
    if stage.stopped_before_joining():
        return

    from zenslam.backend.rerun_log import BackendLog

    with stage.rerun_recording() as recording, stage.open_session() as session:
        node.rerun = BackendLog(recording) if recording is not None else None
        stage.require_alive(session, args.wait_for)
        # The journal lives in the run folder, beside the run's config.yaml; no folder, no journal.
        journal = Path(args.config).parent / JOURNAL_NAME if config.journal and args.config is not None else None
        if args.restart:
            logger.info("restart %d: rebuilding the map from %s", args.restart, journal)
            # What this backend publishes must reach the frontend, which waits for the answers
            # the journal lacks: its token seen here means its subscriptions have reached us too.
            timeout_s = stage.bus_config.start_timeout_s
            if bus.wait_for_alive(session, args.session, ["frontend"], timeout_s, stage.stop.keep_going):
                logger.warning("restart %d: no frontend within %.0f s; mapping on without it", args.restart, timeout_s)
        try:
            serve(session, args.session, node, config, stage.stop, journal=journal, rebuild=args.restart > 0, lockstep=lockstep)
        finally:
            node.close()
        if node.rerun is not None:
            node.rerun.finish()


if __name__ == "__main__":
    sys.exit(main())
