"""``zenslam recover``: a truncated recording becomes an indexed file holding every finished chunk's messages."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
from mcap.reader import make_reader

from zenslam.schemas import codec
from zenslam.service import mcap_io
from zenslam.service.commands import recover


def _recording(path, n: int = 300, chunk_size: int = 2048) -> None:
    with mcap_io.RecordingWriter(path, chunk_size=chunk_size) as writer:
        for i in range(n):
            T = np.eye(4)
            T[0, 3] = i
            writer.write("/frontend/pose", codec.POSE_IN_FRAME, codec.encode_pose_in_frame(codec.StampedPose(i + 1, T)), i + 1)
            writer.write("/frontend/state", codec.TRACKING_STATE, codec.encode_tracking_state(codec.TrackingStateMessage(i, i + 1, "ok")), i + 1)


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    recover.register(parser.add_subparsers())
    return parser.parse_args(argv)


def test_a_truncated_recording_is_recovered_to_an_indexed_prefix(tmp_path, capsys):
    original = tmp_path / "run.mcap"
    _recording(original)
    data = original.read_bytes()
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(data[: int(len(data) * 0.6)])
    args = _parse(["recover", str(broken)])
    assert args.handler(args) == 0
    fixed = tmp_path / "broken.recovered.mcap"
    out = capsys.readouterr().out
    assert "ended early" in out and str(fixed) in out
    with open(fixed, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()  # the index is there
        poses = [m for _, c, m in reader.iter_messages(topics=["/frontend/pose"])]
    assert summary.statistics.channel_count == 2
    n = len(poses)
    assert 100 < n < 300
    assert [m.sequence for m in poses] == list(range(n))
    assert [m.log_time for m in poses] == list(range(1, n + 1))
    # Lost: at most the chunk that was being written when the file was cut (2 KB of ~60-byte messages).
    states = sum(1 for _ in mcap_io.iter_messages(fixed, ["/frontend/state"]))
    assert abs(states - n) <= 1


def test_a_recording_cut_anywhere_is_recovered(tmp_path):
    """A killed recorder may stop at any byte: inside a record's opcode, length field or body."""
    original = tmp_path / "run.mcap"
    _recording(original, n=60)
    data = original.read_bytes()
    kept = []
    for cut in range(len(data) // 2, len(data) // 2 + 120):
        broken, fixed = tmp_path / f"cut{cut}.mcap", tmp_path / f"cut{cut}.fixed.mcap"
        broken.write_bytes(data[:cut])
        report = mcap_io.recover(broken, fixed)
        assert not report.complete and report.stop_reason
        kept.append(report.messages.get("/frontend/pose", 0))
    assert kept == sorted(kept) and kept[-1] > 0  # more bytes never recover fewer messages


def test_a_complete_recording_is_copied_whole(tmp_path):
    original, fixed = tmp_path / "run.mcap", tmp_path / "copy.mcap"
    _recording(original, n=50)
    report = mcap_io.recover(original, fixed)
    assert report.complete and report.stop_reason == ""
    assert report.messages == {"/frontend/pose": 50, "/frontend/state": 50}
    assert (report.schemas, report.channels) == (2, 2)
    before = [(m.topic, m.log_time_ns, m.data) for m in mcap_io.iter_messages(original)]
    after = [(m.topic, m.log_time_ns, m.data) for m in mcap_io.iter_messages(fixed)]
    assert before == after


def test_recovering_a_file_into_itself_is_refused(tmp_path):
    path = tmp_path / "run.mcap"
    _recording(path, n=2)
    with pytest.raises(mcap_io.RecordingError, match="into itself"):
        mcap_io.recover(path, path)


def test_default_output_is_beside_the_input(tmp_path):
    assert recover.default_output(tmp_path / "run.mcap") == tmp_path / "run.recovered.mcap"
