"""The frontend's inbox of the backend's map updates (backend/map_update): when each is applied
in each run mode, and the keyframes still waiting for their answer, sent again to a backend that
comes back after a crash."""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable
from typing import Protocol


from zenslam.frontend.config import FrontendConfig
from zenslam.runtime import bus
from zenslam.schemas import codec, keys
from zenslam.schemas.map_update import MapUpdate

logger = logging.getLogger(__name__)


class SentKeyframes(Protocol):
    """The encoded keyframes one frame sent, and their ids (``FrontendMessages``)."""

    keyframes: tuple[bytes, ...]
    keyframe_ids: tuple[int, ...]


class UpdatedNode(Protocol):
    """What the inbox applies updates through (``FrontendNode``)."""

    def apply_map_update(self, update: MapUpdate) -> None: ...


_RESEND_S = 5.0  # seconds between sends of the unanswered keyframes to a restarted backend, until it answers


class MapUpdateInbox:
    """The backend's map updates, applied through the node as the run mode says, and the
    keyframes still waiting for their answer, sent again to a backend that comes back after a crash
    (it rebuilds its map from its journal; one it had taken already it refuses without an answer)."""

    def __init__(self, session: bus.Session, session_name: str, config: FrontendConfig, resend: Callable[[bytes], None]):
        # Answers to keyframes below this id are to keyframes of a frontend before this one (it
        # crashed): this one entered the map by relocalising and fetches what it needs of it.
        self.first_keyframe_id = config.tracking.local_map.keyframe_id_start
        # Lossless: a missed update would leave the frontend's map behind the backend's for good.
        self.inbox = bus.subscribe(session, keys.backend_map_update(session_name), codec.decode_map_update, "lossless", config.map_update_queue)
        self.timeout_s = config.update_timeout_s
        self.ended = False
        self.unanswered: dict[int, bytes] = {}  # keyframe id -> its message, sent and not answered yet
        self.resent = 0  # keyframes sent again to a restarted backend
        self._last_answered = -1  # the newest keyframe id answered
        # Updates announced and not applied yet: the last answer announces its keyframe's
        # local-mapping correction, which announces the loop corrections after it.
        self.due = 0
        # Lockstep's schedule, in frames handled: (keyframe id, the frame before which its answer is
        # applied), oldest first; and the frame before which the last answer's corrections are
        # applied when it was published before its local BA (None: with the answer).
        self.lag_frames = config.lockstep_lag_frames
        self._answers_due: deque[tuple[int, int]] = deque()
        self._corrections_due: int | None = None
        self._lag_one_frame = False  # the last answer's corrections may wait for the frame after the one it is applied before
        self._resend_due: float | None = None  # after a backend restart: when to send the unanswered again
        self._resend = resend
        self._backend = bus.Comebacks(session, session_name, "backend")

    def sent(self, messages: SentKeyframes) -> None:
        """Note the keyframes just sent: each waits for its answer."""
        self.unanswered.update(zip(messages.keyframe_ids, messages.keyframes, strict=True))

    def schedule(self, messages: SentKeyframes, frames_handled: int) -> None:
        """Lockstep: the keyframes just sent, made at the frame that brought the count of frames
        handled to ``frames_handled``, are answered before frame ``frames_handled - 1 + lag_frames``."""
        for keyframe_id in messages.keyframe_ids:
            self._answers_due.append((keyframe_id, frames_handled - 1 + self.lag_frames))

    def waits_before(self, frame: int, drain: bool) -> bool:
        """Lockstep: whether updates are due before tracking frame ``frame`` (counted in frames
        handled); with ``drain``, whether any is still to come."""
        corrections = self.due > 0 and (drain or (self._corrections_due is not None and self._corrections_due <= frame))
        return corrections or bool(self._answers_due and (drain or self._answers_due[0][1] <= frame))

    def apply_due(self, node: UpdatedNode, frame: int, drain: bool, should_stop: Callable[[], bool]) -> None:
        """Lockstep: apply the updates due before frame ``frame`` (every update to come with
        ``drain``), in the order the backend published them. An answer published before its local BA
        (``corrections_after_next_frame``) leaves its corrections for the frame after."""
        if self.due > 0 and (drain or (self._corrections_due is not None and self._corrections_due <= frame)):
            self.wait_for_corrections(node, should_stop)
        while self._answers_due and (drain or self._answers_due[0][1] <= frame) and not should_stop():
            keyframe_id, _ = self._answers_due.popleft()
            self._wait(node, lambda: self._last_answered >= keyframe_id, f"keyframe {keyframe_id}", should_stop)
            self._corrections_due = frame + 1 if self._lag_one_frame and not drain else None
            if self._corrections_due is None:
                self.wait_for_corrections(node, should_stop)

    def resend_to_a_restarted_backend(self) -> None:
        """When the backend came back since the last call, send it every unanswered keyframe again,
        oldest first: those sent to its predecessor and those held while it was gone. Until an
        answer comes, again every ``_RESEND_S`` seconds: a keyframe sent as the new backend's token
        arrived may not reach it, and one it has already is skipped there."""
        now = time.monotonic()
        if self._backend.returned():
            logger.warning("the backend restarted: sending its %d unanswered keyframe(s) again", len(self.unanswered))
        elif self._resend_due is None or now < self._resend_due or self._backend.gone or not self.unanswered:
            return
        for keyframe_id in sorted(self.unanswered):
            self._resend(self.unanswered[keyframe_id])
            self.resent += 1
        self._resend_due = now + _RESEND_S if self.unanswered else None

    def wait_for_a_restarted_backend(self, timeout_s: float, should_stop: Callable[[], bool]) -> None:
        """At the end of the frames: a backend that is gone gets up to ``timeout_s`` seconds to come
        back and receive the unanswered keyframes, before the end of stream is sent after them."""
        deadline = time.monotonic() + timeout_s
        if self.backend_gone():
            logger.warning("the backend is gone: waiting up to %.0f s for it to restart before ending the stream", timeout_s)
        while self.backend_gone() and not should_stop() and time.monotonic() < deadline:
            time.sleep(0.05)
        self.resend_to_a_restarted_backend()

    def backend_gone(self) -> bool:
        """Whether the backend's process is gone (it crashed, and may be restarted)."""
        self._backend.poll()
        return self._backend.gone

    def apply_pending(self, node: UpdatedNode) -> None:
        """Live: apply every update that has arrived."""
        self.resend_to_a_restarted_backend()
        while not self.ended and (update := self.inbox.get(timeout_s=0)) is not None:
            self._apply(node, update)

    def wait_for_corrections(self, node: UpdatedNode, should_stop: Callable[[], bool]) -> None:
        """Lockstep: apply updates until the last answer's corrections (``due``) have all been applied."""
        self._wait(node, lambda: self.due == 0, f"the corrections of keyframe {self._last_answered}", should_stop)

    def _wait(self, node: UpdatedNode, done: Callable[[], bool], what: str, should_stop: Callable[[], bool]) -> None:
        """Apply updates until ``done()``, the backend has ended its stream (``ended``: it was stopped)
        or ``should_stop()``."""
        deadline = time.monotonic() + self.timeout_s
        while not done() and not should_stop() and not self.ended:
            self.resend_to_a_restarted_backend()
            update = self.inbox.get(timeout_s=0.1)
            if update is not None:
                self._apply(node, update)
                deadline = time.monotonic() + self.timeout_s
            elif time.monotonic() > deadline:
                raise bus.BusError(
                    f"lockstep: no map update for {what} from the backend within {self.timeout_s:.0f} s "
                    "(frontend.update_timeout_s); check the backend's log"
                )

    def _apply(self, node: UpdatedNode, update: MapUpdate | codec.EndOfStream) -> None:
        """Apply one update; the end of stream marks the stream ended."""
        if isinstance(update, codec.EndOfStream):
            self.ended = True
            return
        if update.answers_keyframe:
            if update.keyframe_id < self.first_keyframe_id:
                logger.info("an answer to keyframe %d, made before this frontend restarted: not applied", update.keyframe_id)
                return
            if update.keyframe_id <= self._last_answered:
                # Answers come in keyframe order; a second one is a restarted backend's, for a
                # keyframe whose answer its predecessor published just before dying.
                logger.warning("a second answer to keyframe %d (the backend restarted): ignored", update.keyframe_id)
                return
            self._last_answered = int(update.keyframe_id)
            self.unanswered.pop(int(update.keyframe_id), None)
            self._resend_due = None  # the restarted backend has its keyframes
            self.due = update.corrections_following
            self._lag_one_frame = update.corrections_after_next_frame
        else:
            # A correction: one of those announced (each may announce more after it), or one
            # announced by none (a background global BA's, live or pipelined).
            self.due = max(self.due - 1, 0) + update.corrections_following
        node.apply_map_update(update)

    def close(self) -> None:
        self.inbox.close()
        self._backend.close()
