"""``zenslam export``: per-frame and keyframe trajectories and the final map from a recording."""

from __future__ import annotations

import argparse

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.schemas import codec, keys
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.service import mcap_io
from zenslam.service.commands import export
from zenslam.service.evaluation.trajectory_io import read_tum
from zenslam.service.recorder import Recorder
from zenslam.service.run_config import RecorderConfig

SESSION = "export-test"
CAL = PinholeCalibration(50.0, 50.0, 32.0, 24.0, 64, 48, 0.1)


def _keyframe(kf_id: int, stamp_ns: int, point_ids: list[int], points) -> codec.KeyframeMessage:
    n = 2
    return codec.KeyframeMessage(
        id=kf_id, stamp_ns=stamp_ns, frame_index=kf_id, T_world_cam=np.eye(4), calibration=CAL, sensor="stereo",
        keypoints_px=np.zeros((n, 2), np.float32), levels=np.zeros(n, np.int16), angles_deg=np.zeros(n, np.float32),
        right_u=np.zeros(n, np.float32), depth_m=np.ones(n, np.float32), descriptors=np.zeros((n, 32), np.uint8),
        map_point_ids=np.full(n, -1, np.int64), scale_factors=np.ones(1), new_point_ids=np.array(point_ids, np.int64),
        new_points_world=np.asarray(points, float).reshape(-1, 3),
    )


def _update(kf_id: int, point_ids: list[int], points, removed: list[int]) -> MapUpdate:
    """Moves keyframe ``kf_id`` to y = 5 m, replaces/creates the points, removes ``removed``."""
    p = len(point_ids)
    T = np.eye(4)
    T[1, 3] = 5.0
    return MapUpdate(
        keyframe_id=kf_id, stamp_ns=0, keyframes=(KeyframeCorrection(kf_id, T, np.full(2, -1, np.int64)),),
        point_ids=np.array(point_ids, np.int64), p_world=np.asarray(points, float).reshape(-1, 3),
        descriptors=np.zeros((p, 32), np.uint8), normals=np.zeros((p, 3)), min_distance_m=np.zeros(p), max_distance_m=np.zeros(p),
        removed_point_ids=np.array(removed, np.int64),
    )


def _write(path) -> None:
    messages = []
    for i in range(5):
        T = np.eye(4)
        T[:3, 3] = (0.1 * i, 0.0, 0.0)
        messages.append((keys.frontend_pose(SESSION), codec.POSE_IN_FRAME, codec.encode_pose_in_frame(codec.StampedPose(100 * (i + 1), T))))
        # Frames 0-2 are kept relative to keyframe 0 (at the origin when tracked), 3-4 to keyframe 1.
        state = codec.TrackingStateMessage(i, 100 * (i + 1), "ok", has_pose=True, reference_keyframe_id=int(i >= 3),
                                           T_reference_cam=T if i < 3 else np.eye(4))  # fmt: skip
        messages.append((keys.frontend_state(SESSION), codec.TRACKING_STATE, codec.encode_tracking_state(state)))
    messages.insert(1, (keys.frontend_keyframe(SESSION), codec.KEYFRAME, codec.encode_keyframe(_keyframe(0, 100, [1, 2], [[0, 0, 1], [0, 0, 2]]))))
    messages.insert(2, (keys.backend_map_update(SESSION), codec.MAP_UPDATE, codec.encode_map_update(_update(0, [7], [[1, 2, 3]], removed=[1]))))
    messages.append((keys.frontend_keyframe(SESSION), codec.KEYFRAME, codec.encode_keyframe(_keyframe(1, 400, [8], [[4, 5, 6]]))))
    with mcap_io.RecordingWriter(path) as writer:
        recorder = Recorder(writer, RecorderConfig(), SESSION)
        for key, schema, data in messages:
            recorder.record(key, f"application/protobuf;{schema}", data)


def test_export_writes_trajectories_and_points(tmp_path):
    recording = tmp_path / "run.mcap"
    _write(recording)
    result = export.export_recording(recording, tmp_path / "out")
    assert (result.poses, result.keyframes, result.points) == (5, 2, 3)
    trajectory = read_tum(tmp_path / "out" / "trajectory.tum")
    assert trajectory.stamps_ns.tolist() == [100, 200, 300, 400, 500]
    np.testing.assert_allclose(trajectory.T_world_cam[3, :3, 3], (0.3, 0.0, 0.0), atol=1e-9)
    keyframes = read_tum(tmp_path / "out" / "keyframes.tum")
    assert keyframes.stamps_ns.tolist() == [100, 400]
    np.testing.assert_allclose(keyframes.T_world_cam[0, :3, 3], (0.0, 5.0, 0.0), atol=1e-9)  # the backend's correction
    # Frames on keyframe 0 follow its correction (y = 5 m); keyframe 1 was never corrected: as tracked.
    final = read_tum(tmp_path / "out" / "trajectory_final.tum")
    np.testing.assert_allclose(final.T_world_cam[:, :3, 3], [[0, 5, 0], [0.1, 5, 0], [0.2, 5, 0], [0.3, 0, 0], [0.4, 0, 0]], atol=1e-9)
    lines = (tmp_path / "out" / "points.ply").read_text().splitlines()
    assert "element vertex 3" in lines
    points = np.array([[float(v) for v in line.split()] for line in lines[lines.index("end_header") + 1:]])
    np.testing.assert_allclose(points, [[0, 0, 2], [1, 2, 3], [4, 5, 6]])


def test_the_command_defaults_to_an_export_folder_beside_the_recording(tmp_path, capsys):
    recording = tmp_path / "run.mcap"
    _write(recording)
    parser = argparse.ArgumentParser()
    export.register(parser.add_subparsers())
    args = parser.parse_args(["export", str(recording)])
    assert args.handler(args) == 0
    assert {p.name for p in (tmp_path / "export").iterdir()} == {"trajectory.tum", "trajectory_final.tum", "keyframes.tum", "points.ply"}
    assert "5 poses, 2 keyframes, 3 map points" in capsys.readouterr().out


def test_a_recording_without_poses_writes_only_the_map(tmp_path):
    recording = tmp_path / "run.mcap"
    with mcap_io.RecordingWriter(recording):
        pass
    result = export.export_recording(recording, tmp_path / "out")
    assert set(result.written) == {"points.ply"} and result.points == 0
