"""A run folder's outputs from its recording equal those of the RunLog that ``zenslam run`` fills from the bus."""

from __future__ import annotations

import json

import numpy as np

from zenslam.schemas import codec, keys
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.service import mcap_io
from zenslam.service.recorded_ground_truth import encode_ground_truth
from zenslam.service.recorded_run import run_log_from_recording, write_recorded_outputs
from zenslam.service.recorder import Recorder
from zenslam.service.run_config import RecorderConfig, RunConfig
from zenslam.service.run_output import RunLog, write_outputs
from zenslam.trajectory import Trajectory

SESSION = "recorded-test"
FRAMES = 6


def _pose(k: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (0.1 * k, 0.02 * k * k, 0.03 * (k % 2))
    return T


def _messages() -> list[tuple[str, str, object, bytes]]:
    """(key, schema, decoded, bytes) of a short run: states, poses, a map update, statuses, ends of stream."""
    out = []

    def add(key: str, schema: str, decoded: object, data: bytes) -> None:
        out.append((key, schema, decoded, data))

    truth = Trajectory(np.array([1_000 + k for k in range(FRAMES)], dtype=np.int64), np.stack([_pose(k) for k in range(FRAMES)]))
    add(keys.source_ground_truth(SESSION), codec.KEYFRAME_TRAJECTORY, None, encode_ground_truth(truth))
    for k in range(FRAMES):
        state = codec.TrackingStateMessage(
            k, 1_000 + k, "ok" if k != 3 else "lost", has_pose=k != 3, keyframe_id=0 if k == 0 else -1,
            reference_keyframe_id=0, T_reference_cam=_pose(k), timings_ms={"total": 1.0 + k},
        )
        add(keys.frontend_state(SESSION), codec.TRACKING_STATE, state, codec.encode_tracking_state(state))
        if state.has_pose:
            pose = codec.StampedPose(1_000 + k, _pose(k))
            add(keys.frontend_pose(SESSION), codec.POSE_IN_FRAME, pose, codec.encode_pose_in_frame(pose))
    T_corrected = _pose(0)
    T_corrected[2, 3] = 0.01
    update = MapUpdate(keyframe_id=0, stamp_ns=1_000, keyframes=(KeyframeCorrection(0, T_corrected, np.full(2, -1, np.int64)),))
    add(keys.backend_map_update(SESSION), codec.MAP_UPDATE, update, codec.encode_map_update(update))
    status = codec.StageStatusMessage("source", "finished", FRAMES, skipped={"corrupt": 1})
    add(keys.status(SESSION, "source"), codec.STAGE_STATUS, status, codec.encode_stage_status(status))
    add(keys.frontend_state(SESSION), codec.TRACKING_STATE, codec.EndOfStream(FRAMES), codec.encode_end_of_stream(codec.TRACKING_STATE, FRAMES))
    add(keys.backend_map_update(SESSION), codec.MAP_UPDATE, codec.EndOfStream(1), codec.encode_end_of_stream(codec.MAP_UPDATE, 1))
    return out


def _recording(tmp_path):
    path = tmp_path / "run.mcap"
    with mcap_io.RecordingWriter(path) as writer:
        recorder = Recorder(writer, RecorderConfig(), SESSION)
        for key, schema, _, data in _messages():
            recorder.record(key, f"application/protobuf;{schema}", data)
    return path, recorder


def _followed_log() -> RunLog:
    """The RunLog as ``zenslam run``'s follower fills it from the same messages."""
    log = RunLog()
    for key, _, decoded, _ in _messages():
        if key == keys.frontend_state(SESSION):
            if isinstance(decoded, codec.EndOfStream):
                log.ended = True
            else:
                log.add_state(decoded)
        elif key == keys.frontend_pose(SESSION):
            log.add_pose(decoded)
        elif key == keys.backend_map_update(SESSION):
            log.add_map_update(decoded)
        elif key.endswith("/status"):
            log.add_status(decoded)
    return log


def test_the_recorder_notes_the_streams_that_ended(tmp_path):
    _, recorder = _recording(tmp_path)
    assert recorder.ended_topics == {"/frontend/state", "/backend/map_update"}


def test_outputs_from_the_recording_equal_those_of_the_followed_run(tmp_path):
    path, _ = _recording(tmp_path)
    log = run_log_from_recording(path)
    assert log.ended and log.backend_ended and log.source_skipped == {"corrupt": 1}
    (tmp_path / "followed").mkdir()
    (tmp_path / "recorded").mkdir()
    write_outputs(tmp_path / "followed", _followed_log(), None, RunConfig().evaluation)
    write_outputs(tmp_path / "recorded", log, None, RunConfig().evaluation)
    for name in ("trajectory.tum", "trajectory_final.tum", "keyframes.tum"):
        assert (tmp_path / "recorded" / name).read_bytes() == (tmp_path / "followed" / name).read_bytes(), name
    assert len((tmp_path / "recorded" / "trajectory.tum").read_text().splitlines()) == 1 + FRAMES - 1  # the lost frame has no pose


def test_write_recorded_outputs_scores_against_the_recorded_ground_truth(tmp_path):
    path, _ = _recording(tmp_path)
    backend = codec.KeyframeTrajectoryMessage(np.array([0]), np.array([1_000]), _pose(0)[None], 1, True)
    result = write_recorded_outputs(tmp_path, path, RunConfig(), SESSION, backend, stopped=False)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert result.evaluation is not None and metrics["ate"]["matched_poses"] == FRAMES - 1
    assert metrics["run"] == {"run_id": SESSION, "source": RunConfig().source.spec, "mode": "lockstep", "completed": True}
    assert metrics["keyframes_from"] == "backend" and metrics["skipped_frames"]["total"] == 1
