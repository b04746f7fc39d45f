"""A restarted backend's map rebuilt from the journal (``journal``), and the answers it lacks published.

Mapping is deterministic given its inputs, so replaying the journaled keyframes through a fresh node
gives the map that was lost; the answers never published (at most the keyframe in hand when the
process died) go out afterwards, in order.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from zenslam.backend.journal import Answered, Entry, JournaledKeyframe, JournalWriter, read_journal
from zenslam.backend.outputs import STAGE, BackendOutputs, StepOutput
from zenslam.schemas import codec
from zenslam.schemas.map_update import MapUpdate

if TYPE_CHECKING:
    from zenslam.backend.rerun_log import BackendLog

logger = logging.getLogger(__name__)


class Rebuilding(Protocol):
    """What the rebuild asks of the map's owner (``BackendNode``)."""

    rerun: BackendLog | None
    processed: int

    @property
    def newest_id(self) -> int: ...

    def step(self, keyframe: codec.KeyframeMessage, queued: int = 0) -> StepOutput: ...

    def finish_global_ba(self) -> MapUpdate | None: ...


def journal_entries(journal: Path) -> list[Entry]:
    """The records of ``journal``; none (the map starts empty) when the file does not exist."""
    if not journal.exists():
        logger.warning("restarted without a journal at %s: the map starts empty", journal)
        return []
    return read_journal(journal)


def rebuild_from_journal(
    outputs: BackendOutputs, node: Rebuilding, entries: list[Entry], journal: JournalWriter | None, should_stop: Callable[[], bool]
) -> int:
    """Replay the journal's keyframes through ``node`` (rerun logging off: the predecessor logged
    them), then publish the answers that were never published, in order, and journal them; returns
    the newest keyframe id rebuilt (-1: none)."""
    started = time.perf_counter()
    unanswered: dict[int, StepOutput] = {}
    rerun, node.rerun = node.rerun, None
    try:
        for entry in entries:
            if should_stop():
                return node.newest_id
            if isinstance(entry, JournaledKeyframe):
                keyframe = codec.decode_keyframe(entry.message)
                unanswered[int(keyframe.id)] = node.step(keyframe, entry.queued)
                # Heard while rebuilding: a supervisor watching for hung stages sees progress.
                outputs.send_status(codec.StageStatusMessage(STAGE, "starting", node.processed, detail="rebuilding from the journal"))
            elif isinstance(entry, Answered):
                unanswered.pop(entry.keyframe_id, None)
            else:
                node.finish_global_ba()  # a background global BA was applied here: wait for the same one, apply it
    finally:
        node.rerun = rerun
    logger.info(
        "rebuilt the map from the journal: %d keyframes in %.1f s; %d answer(s) not published before, publishing them",
        node.processed, time.perf_counter() - started, len(unanswered),
    )  # fmt: skip
    for keyframe_id, output in unanswered.items():
        outputs.send_step(output)
        if journal is not None:
            journal.answered(keyframe_id)
    return node.newest_id
