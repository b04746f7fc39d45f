"""The backend's journal: records round trip, a record cut short by a crash is ignored, other files are refused."""

from __future__ import annotations

import logging

import pytest

from zenslam.backend.journal import (
    MAGIC,
    Answered,
    GlobalBAApplied,
    JournaledKeyframe,
    JournalError,
    JournalWriter,
    read_journal,
)


def _write(path) -> list:
    """Two writers in turn, as a backend and its restarted successor; returns the entries written."""
    with JournalWriter(path) as journal:
        journal.keyframe(b"keyframe 0 bytes", 0)
        journal.answered(0)
    with JournalWriter(path) as journal:
        journal.keyframe(b"\x00\xff" * 500, 2)
        journal.global_ba_applied()
    return [JournaledKeyframe(b"keyframe 0 bytes", 0), Answered(0), JournaledKeyframe(b"\x00\xff" * 500, 2), GlobalBAApplied()]


def test_entries_come_back_in_order_across_reopenings(tmp_path):
    path = tmp_path / "backend.journal"
    expected = _write(path)
    assert read_journal(path) == expected
    assert path.read_bytes().count(MAGIC) == 1  # appending does not write the header again


def test_an_answer_keeps_negative_and_large_ids(tmp_path):
    path = tmp_path / "j"
    with JournalWriter(path) as journal:
        for keyframe_id in (-1, 2**40):
            journal.answered(keyframe_id)
    assert read_journal(path) == [Answered(-1), Answered(2**40)]


@pytest.mark.parametrize("cut", [1, 5, 9, 20])
def test_a_record_cut_short_by_a_crash_ends_the_entries_with_a_warning(tmp_path, caplog, cut):
    path = tmp_path / "backend.journal"
    expected = _write(path)
    data = path.read_bytes()
    last_record = 9  # the G record: header only
    keyframe_record = 9 + 4 + 1000
    path.write_bytes(data[: len(data) - last_record - keyframe_record + cut])  # the second keyframe's record, cut
    with caplog.at_level(logging.WARNING):
        assert read_journal(path) == expected[:2]
    assert "incomplete" in caplog.text


def test_a_damaged_last_record_fails_its_checksum_and_is_ignored(tmp_path):
    path = tmp_path / "backend.journal"
    expected = _write(path)
    data = bytearray(path.read_bytes())
    data[-20] ^= 0xFF  # inside the second keyframe's payload, followed by the G record
    path.write_bytes(bytes(data))
    assert read_journal(path) == expected[:2]


def test_a_file_that_is_no_journal_is_refused(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("not a journal")
    with pytest.raises(JournalError, match="not a zenslam backend journal"):
        read_journal(path)
    with pytest.raises(JournalError, match="cannot read"):
        read_journal(tmp_path / "missing")


def test_an_unknown_record_names_its_kind_and_place(tmp_path):
    import struct
    import zlib

    path = tmp_path / "backend.journal"
    path.write_bytes(MAGIC + struct.pack("<cII", b"Z", 3, zlib.crc32(b"abc")) + b"abc")
    with pytest.raises(JournalError, match=r"unknown record b'Z' of 3 bytes at byte 8"):
        read_journal(path)
