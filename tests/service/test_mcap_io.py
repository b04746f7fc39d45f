"""MCAP helpers: topics from keys, embedded schemas any protobuf MCAP reader decodes, reading back, truncated files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from zenslam.schemas import codec, keys
from zenslam.service import mcap_io


def _pose(i: int) -> bytes:
    T = np.eye(4)
    T[:3, 3] = (i, 2.0 * i, -1.0)
    return codec.encode_pose_in_frame(codec.StampedPose(1_000 + i, T))


def _write_poses(path: Path, n: int, chunk_size: int = 1024) -> None:
    with mcap_io.RecordingWriter(path, chunk_size=chunk_size) as writer:
        for i in range(n):
            writer.write("/frontend/pose", codec.POSE_IN_FRAME, _pose(i), 1_000 + i)
            writer.write("/backend/status", codec.STAGE_STATUS, codec.encode_stage_status(codec.StageStatusMessage("backend", "running", i)), 1_000 + i)


def test_topic_is_the_key_without_the_session_prefix():
    assert mcap_io.topic_for_key(keys.frontend_pose("s1"), "s1") == "/frontend/pose"
    assert mcap_io.topic_for_key(keys.status("s1", "backend"), "s1") == "/backend/status"
    assert mcap_io.topic_for_key("other/key", "s1") == "/other/key"


def test_schema_name_comes_from_the_zenoh_encoding():
    assert mcap_io.schema_from_encoding("application/protobuf;zenslam.Keyframe") == "zenslam.Keyframe"
    assert mcap_io.schema_from_encoding("application/protobuf") is None
    assert mcap_io.schema_from_encoding("application/protobuf;") is None


def test_written_messages_read_back_decoded_in_order(tmp_path):
    path = tmp_path / "run.mcap"
    _write_poses(path, 20)
    assert mcap_io.has_summary(path)
    got = list(mcap_io.iter_decoded(path, ["/frontend/pose"]))
    assert [m.sequence for m, _ in got] == list(range(20))
    assert [m.log_time_ns for m, _ in got] == [1_000 + i for i in range(20)]
    np.testing.assert_allclose(got[7][1].T_world_cam[:3, 3], (7.0, 14.0, -1.0), atol=1e-12)


def test_embedded_schemas_decode_with_mcap_protobuf_support(tmp_path):
    path = tmp_path / "run.mcap"
    _write_poses(path, 3)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        decoded = list(reader.iter_decoded_messages())
        summary = reader.get_summary()
    assert {s.name for s in summary.schemas.values()} == {"foxglove.PoseInFrame", "zenslam.StageStatus"}
    assert {s.encoding for s in summary.schemas.values()} == {"protobuf"}
    pose = next(m for _, c, _, m in decoded if c.topic == "/frontend/pose")
    assert pose.pose.position.z == -1.0


def test_a_truncated_file_is_read_up_to_its_last_complete_chunk(tmp_path):
    path = tmp_path / "run.mcap"
    _write_poses(path, 200, chunk_size=2048)
    data = path.read_bytes()
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(data[: len(data) // 2])
    assert not mcap_io.has_summary(broken)
    poses = [m for m in mcap_io.iter_messages(broken, ["/frontend/pose"])]
    assert 50 < len(poses) < 200
    assert [m.sequence for m in poses] == list(range(len(poses)))  # a prefix, nothing invented
    end = mcap_io.StreamEnd()
    list(mcap_io.stream_records(broken, end))
    assert not end.complete and end.reason


def test_not_an_mcap_file_is_refused_with_its_path(tmp_path):
    path = tmp_path / "x.mcap"
    path.write_bytes(b"hello world")
    with pytest.raises(mcap_io.RecordingError, match="x.mcap is not an MCAP file"):
        mcap_io.has_summary(path)
    with pytest.raises(mcap_io.RecordingError, match="does not exist"):
        list(mcap_io.iter_messages(tmp_path / "missing.mcap"))


def test_one_topic_keeps_one_schema(tmp_path):
    with mcap_io.RecordingWriter(tmp_path / "run.mcap") as writer:
        writer.write("/frontend/pose", codec.POSE_IN_FRAME, _pose(0), 0)
        with pytest.raises(mcap_io.RecordingError, match="one topic, one schema"):
            writer.write("/frontend/pose", codec.STAGE_STATUS, b"", 0)


def test_unknown_schema_is_an_error_naming_it():
    with pytest.raises(mcap_io.RecordingError, match="nope.Thing"):
        mcap_io.schema_data("nope.Thing")
