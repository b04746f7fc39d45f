"""The backend's journal: every keyframe it accepted, in order, so that a restarted backend rebuilds its map.

A backend process that dies (an out-of-memory kill, a segfault in a native library) loses its map;
the keyframes that built it are gone from the bus. Before mapping a keyframe the backend appends the
keyframe's message, as it came off the bus, to ``backend.journal`` in the run folder, with what else
decided the step (how many keyframes were queued behind it), and after publishing the step's map
updates it appends that the keyframe was answered. A restarted backend replays the journal through a
fresh ``BackendNode``: mapping is deterministic given its inputs, so the rebuilt map is the one that
was lost, bit for bit, and the answers the frontend never received (at most the keyframe in hand
when the process died) are published then. A global BA that ran in a helper process (pipelined and
live runs) is journaled where its result was applied, so the replay applies it at the same point.

Why a journal of its own rather than the run's recording: run.mcap is written in compressed
chunks that stay in the recorder's memory until full (megabytes of camera frames), the recorder may
be off or on another machine, and the journal holds only what the backend needs (the keyframes, a
small part of a run's recording). Records are flushed to the operating system as they are written,
so they survive the death of the process; a record cut short by a crash is ignored when read.

Format (version 1): the 8 bytes ``ZSLAMJ1\\n``, then records of kind (1 byte), payload length
(4 bytes, little endian), CRC-32 of the payload (4 bytes, little endian) and the payload:

- ``K``: a keyframe accepted for mapping: keyframes queued behind it (4 bytes, little endian), then
  the frontend/keyframe message as received;
- ``A``: the keyframe with this id (8 bytes, little endian, signed) was answered;
- ``G``: a global BA run in a helper process was applied here (empty payload).
"""

from __future__ import annotations

import logging
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Literal

from zenslam.errors import ZenslamError

logger = logging.getLogger(__name__)

JOURNAL_NAME = "backend.journal"
MAGIC = b"ZSLAMJ1\n"
_HEADER = struct.Struct("<cII")  # kind, payload length, CRC-32 of the payload
_QUEUED = struct.Struct("<I")
_KEYFRAME_ID = struct.Struct("<q")


class JournalError(ZenslamError):
    """A journal that cannot be used: not a journal, or not readable."""


@dataclass(frozen=True)
class JournaledKeyframe:
    """A keyframe the backend accepted, as it came off the bus, and the keyframes queued behind it then."""

    message: bytes
    queued: int


@dataclass(frozen=True)
class Answered:
    """The keyframe ``keyframe_id``'s map updates were published."""

    keyframe_id: int


@dataclass(frozen=True)
class GlobalBAApplied:
    """A background global BA's result was applied to the map at this point."""


Entry = JournaledKeyframe | Answered | GlobalBAApplied


class JournalWriter:
    """Appends records to a journal, flushing each to the operating system."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._file: BinaryIO = open(self.path, "ab")  # noqa: SIM115 (closed by close())
        except OSError as exc:
            raise JournalError(f"cannot open the backend journal {self.path} for writing: {exc}") from exc
        if self._file.tell() == 0:
            self._file.write(MAGIC)
            self._file.flush()

    def keyframe(self, message: bytes, queued: int) -> None:
        self._write(b"K", _QUEUED.pack(queued) + message)

    def answered(self, keyframe_id: int) -> None:
        self._write(b"A", _KEYFRAME_ID.pack(keyframe_id))

    def global_ba_applied(self) -> None:
        self._write(b"G", b"")

    def _write(self, kind: Literal[b"K", b"A", b"G"], payload: bytes) -> None:
        self._file.write(_HEADER.pack(kind, len(payload), zlib.crc32(payload)) + payload)
        self._file.flush()

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> JournalWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_journal(path: str | Path) -> list[Entry]:
    """The journal's entries in order. A last record cut short (the process died while writing it)
    or failing its checksum ends the entries with a warning; a file that is no journal raises."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise JournalError(f"cannot read the backend journal {path}: {exc}") from exc
    if not data.startswith(MAGIC):
        raise JournalError(f"{path} is not a zenslam backend journal (it does not start with {MAGIC!r})")
    entries: list[Entry] = []
    offset = len(MAGIC)
    while offset < len(data):
        if offset + _HEADER.size > len(data):
            _warn_cut(path, offset, len(data))
            break
        kind, length, crc = _HEADER.unpack_from(data, offset)
        start = offset + _HEADER.size
        payload = data[start : start + length]
        if len(payload) < length or zlib.crc32(payload) != crc:
            _warn_cut(path, offset, len(data))
            break
        entries.append(_entry(path, kind, payload, offset))
        offset = start + length
    return entries


def _entry(path: Path, kind: bytes, payload: bytes, offset: int) -> Entry:
    if kind == b"K" and len(payload) >= _QUEUED.size:
        return JournaledKeyframe(payload[_QUEUED.size :], _QUEUED.unpack_from(payload)[0])
    if kind == b"A" and len(payload) == _KEYFRAME_ID.size:
        return Answered(_KEYFRAME_ID.unpack(payload)[0])
    if kind == b"G" and not payload:
        return GlobalBAApplied()
    raise JournalError(f"{path}: unknown record {kind!r} of {len(payload)} bytes at byte {offset}; it was written by another version")


def _warn_cut(path: Path, offset: int, size: int) -> None:
    logger.warning(
        "%s: the record at byte %d is incomplete (the backend died while writing it); %d bytes ignored",
        path, offset, size - offset,
    )  # fmt: skip
