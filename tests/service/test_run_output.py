"""Run outputs: which poses go in the trajectories, the timing table, and the files metrics.json and the plot."""

from __future__ import annotations

import json

import numpy as np
import pytest

from zenslam.errors import ConfigError
from zenslam.geometry import make_T, so3_exp
from zenslam.schemas import codec
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.service.evaluation.metrics import EvaluationConfig
from zenslam.service.evaluation.trajectory_io import read_tum
from zenslam.service.run_config import RunConfig, load_run_config
from zenslam.service.run_output import (
    RunLog,
    evaluation_config_for,
    prepare_run_dir,
    write_config,
    write_outputs,
)
from zenslam.trajectory import Trajectory

PERIOD_NS = 50_000_000


def _truth(n: int) -> Trajectory:
    stamps = np.arange(n, dtype=np.int64) * PERIOD_NS + 1_000_000_000
    poses = np.stack([make_T(so3_exp(np.array([0.0, 0.02 * i, 0.0])), [0.1 * i, 0.0, 0.01 * i * i]) for i in range(n)])
    return Trajectory(stamps, poses)


def _log(truth: Trajectory, lost: set[int], keyframes: set[int], rng: np.random.Generator) -> RunLog:
    """States and poses as the run command receives them; estimates are the truth with 1 mm noise."""
    log = RunLog()
    for i, stamp in enumerate(truth.stamps_ns):
        ok = i not in lost
        log.add_state(
            codec.TrackingStateMessage(
                index=i, stamp_ns=int(stamp), state="ok" if ok else "lost", lost_reason=None if ok else "too few matches",
                n_tracked=100, timings_ms={"total": 10.0 + i, "extraction": 5.0}, has_pose=ok,
                keyframe_id=sorted(keyframes).index(i) if i in keyframes else -1,
            )
        )
        if ok:
            T = truth.T_world_cam[i].copy()
            T[:3, 3] += rng.normal(scale=0.001, size=3)
            log.add_pose(codec.StampedPose(int(stamp), T))
    return log


def test_trajectories_hold_ok_frames_and_keyframes():
    truth = _truth(10)
    log = _log(truth, lost={3, 4}, keyframes={0, 5, 9}, rng=np.random.default_rng(0))
    assert log.missing_poses() == 0
    est = log.trajectory()
    assert list(est.stamps_ns) == [s for i, s in enumerate(truth.stamps_ns) if i not in (3, 4)]
    assert list(log.keyframe_trajectory().stamps_ns) == [truth.stamps_ns[i] for i in (0, 5, 9)]


def test_final_trajectory_follows_the_reference_keyframes_final_poses():
    """Frames 0-2 refer to keyframe 0 (in the backend's answer), 3 to keyframe 1 (culled: its last
    correction), 4 to keyframe 2 (never corrected: kept as tracked)."""
    log = RunLog()
    tracked = [make_T(np.eye(3), [float(i), 0.0, 0.0]) for i in range(5)]
    relative = [make_T(so3_exp(np.array([0.0, 0.1 * i, 0.0])), [0.0, 0.0, 0.5 * i]) for i in range(5)]
    for i, reference in enumerate([0, 0, 0, 1, 2]):
        log.add_state(codec.TrackingStateMessage(i, 10 * (i + 1), "ok", has_pose=True, reference_keyframe_id=reference,
                                                 T_reference_cam=relative[i]))  # fmt: skip
        log.add_pose(codec.StampedPose(10 * (i + 1), tracked[i]))
    moved = {k: make_T(so3_exp(np.array([0.0, 0.0, 0.2 * k])), [1.0, 2.0, float(k)]) for k in (0, 1)}
    log.add_map_update(MapUpdate(keyframe_id=1, stamp_ns=0, keyframes=(KeyframeCorrection(1, moved[1], np.zeros(0, np.int64)),)))
    log.backend_keyframes = codec.KeyframeTrajectoryMessage(np.array([0]), np.array([10]), moved[0][None])
    final = log.final_trajectory()
    expected = [moved[0] @ relative[0], moved[0] @ relative[1], moved[0] @ relative[2], moved[1] @ relative[3], tracked[4]]
    np.testing.assert_allclose(final.T_world_cam, np.stack(expected), atol=1e-12)
    np.testing.assert_array_equal(final.stamps_ns, [10, 20, 30, 40, 50])


def test_final_trajectory_follows_culled_keyframes_where_the_backend_puts_them():
    """Frame 0 refers to keyframe 3, culled: the backend's answer places it (through its parent), so
    its last map-update correction no longer counts."""
    log = RunLog()
    relative = make_T(so3_exp(np.array([0.0, 0.1, 0.0])), [0.0, 0.0, 0.5])
    log.add_state(codec.TrackingStateMessage(0, 10, "ok", has_pose=True, reference_keyframe_id=3, T_reference_cam=relative))
    log.add_pose(codec.StampedPose(10, np.eye(4)))
    stale = make_T(np.eye(3), [9.0, 9.0, 9.0])
    log.add_map_update(MapUpdate(keyframe_id=3, stamp_ns=0, keyframes=(KeyframeCorrection(3, stale, np.zeros(0, np.int64)),)))
    culled_pose = make_T(so3_exp(np.array([0.0, 0.0, 0.3])), [1.0, 2.0, 3.0])
    log.backend_keyframes = codec.KeyframeTrajectoryMessage(
        np.array([0]), np.array([5]), np.eye(4)[None],
        culled_keyframe_ids=np.array([3]), culled_stamps_ns=np.array([8]), culled_T_world_cam=culled_pose[None],
    )  # fmt: skip
    np.testing.assert_allclose(log.final_trajectory().T_world_cam[0], culled_pose @ relative, atol=1e-12)
    np.testing.assert_array_equal(log.keyframe_trajectory().stamps_ns, [5])  # keyframes.tum: the map's keyframes


def test_without_the_backends_answer_keyframes_take_its_updates_and_lose_the_culled():
    """An interrupted run: keyframes 0-2 made by the frontend, keyframe 1 moved by a map update, keyframe 2 culled."""
    log = RunLog()
    tracked = [make_T(np.eye(3), [float(i), 0.0, 0.0]) for i in range(4)]
    for i in range(4):
        log.add_state(codec.TrackingStateMessage(i, 10 * (i + 1), "ok", has_pose=True, keyframe_id=i if i < 3 else -1))
        log.add_pose(codec.StampedPose(10 * (i + 1), tracked[i]))
    moved = make_T(so3_exp(np.array([0.0, 0.1, 0.0])), [1.0, 0.5, 0.0])
    log.add_map_update(MapUpdate(keyframe_id=1, stamp_ns=20, keyframes=(KeyframeCorrection(1, moved, np.zeros(0, np.int64)),)))
    log.add_map_update(MapUpdate(keyframe_id=2, stamp_ns=30, removed_keyframe_ids=np.array([2], dtype=np.int64)))
    keyframes = log.keyframe_trajectory()
    np.testing.assert_array_equal(keyframes.stamps_ns, [10, 20])
    np.testing.assert_allclose(keyframes.T_world_cam, np.stack([tracked[0], moved]), atol=1e-12)


def test_stages_stopped_before_their_input_ended_are_noted():
    log = RunLog()
    log.add_status(codec.StageStatusMessage("source", "finished", 5))
    log.add_status(codec.StageStatusMessage("frontend", "finished", 5, detail="stopped"))
    log.add_status(codec.StageStatusMessage("backend", "running", 1, 30.0, 2, timings_ms={"total": 30.0}))
    assert log.stopped_stages == ["frontend"]
    assert log.backend_timing()["total"]["keyframes"] == 1 and log.backend_queue_max == 2


def test_a_run_stopped_before_any_frame_still_writes_every_file(tmp_path):
    result = write_outputs(tmp_path, RunLog(), _truth(5), EvaluationConfig(), extra={"run": {"completed": False}})
    assert {p.name for p in result.files} == {"trajectory.tum", "trajectory_final.tum", "keyframes.tum", "metrics.json"}
    for name in ("trajectory.tum", "trajectory_final.tum", "keyframes.tum"):
        assert [line for line in (tmp_path / name).read_text().splitlines() if not line.startswith("#")] == []
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["frames"] == 0 and metrics["run"] == {"completed": False} and metrics["evaluation_error"]


def test_missing_poses_are_counted():
    log = RunLog()
    log.add_state(codec.TrackingStateMessage(0, 10, "ok", has_pose=True))
    log.add_state(codec.TrackingStateMessage(1, 20, "lost", has_pose=False))
    assert log.missing_poses() == 1
    log.add_pose(codec.StampedPose(10, np.eye(4)))
    assert log.missing_poses() == 0


def test_timing_table_and_frame_counts():
    log = _log(_truth(5), lost={2}, keyframes={0}, rng=np.random.default_rng(1))
    timing = log.timing()
    assert timing["total"] == {"mean_ms": 12.0, "median_ms": 12.0, "max_ms": 14.0, "frames": 5}
    assert timing["extraction"]["max_ms"] == 5.0
    counts = log.frame_counts()
    assert counts == {
        "frames": 5, "tracked_ok": 4, "lost_frames": 1, "lost_reasons": {"too few matches": 1},
        "initializing_frames": 0, "initializing_reasons": {}, "keyframes": 1,
    }  # fmt: skip


def test_frames_waiting_for_a_monocular_map_are_counted_by_reason():
    log = RunLog()
    for index, reason in enumerate(["waiting_for_second_frame", "waiting_for_parallax", "waiting_for_parallax"]):
        log.add_state(codec.TrackingStateMessage(index, index * 10, "initializing", lost_reason=reason))
    log.add_state(codec.TrackingStateMessage(3, 30, "ok", has_pose=True, keyframe_id=1))
    counts = log.frame_counts()
    assert (counts["initializing_frames"], counts["lost_frames"], counts["tracked_ok"]) == (3, 0, 1)
    assert counts["initializing_reasons"] == {"waiting_for_parallax": 2, "waiting_for_second_frame": 1}
    # The frame that started the map made two keyframes (0 from the reference frame, 1 its own).
    assert log.keyframe_counts()["sent"] == 2


def test_relocalisation_counts_relocalised_frames_frames_without_a_pose_and_new_maps():
    log = RunLog()
    plan = [  # (state, has_pose, relocalised)
        ("initializing", False, False), ("ok", True, False), ("lost", False, False), ("lost", False, False),
        ("ok", True, True), ("lost", False, False), ("initializing", False, False), ("initializing", True, False),
        ("ok", True, False),
    ]  # fmt: skip
    for i, (state, has_pose, relocalised) in enumerate(plan):
        log.add_state(codec.TrackingStateMessage(i, i, state, has_pose=has_pose, relocalised=relocalised))
    # The frame before the first map is no lost frame; the first map is no new one.
    assert log.relocalisation_counts() == {"count": 1, "frames_lost": 4, "new_maps": 1}
    assert RunLog().relocalisation_counts() == {"count": 0, "frames_lost": 0, "new_maps": 0}


def test_outputs_with_ground_truth(tmp_path):
    truth = _truth(20)
    log = _log(truth, lost={7}, keyframes={0, 10}, rng=np.random.default_rng(2))
    result = write_outputs(tmp_path, log, truth, EvaluationConfig(), extra={"run": {"run_id": "x"}})
    assert {p.name for p in result.files} == {
        "trajectory.tum", "trajectory_final.tum", "keyframes.tum", "metrics.json", "trajectory_top.png"
    }
    # No reference keyframes in these states: the final trajectory is the tracked one.
    assert json.loads((tmp_path / "metrics.json").read_text())["ate_final"]["rmse_m"] == pytest.approx(result.evaluation.ate.rmse_m)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["ate"]["rmse_m"] < 0.003  # 1 mm noise per axis: about 1.7 mm
    assert metrics["ate"]["matched_poses"] == 19
    assert metrics["frames"] == 20 and metrics["lost_frames"] == 1 and metrics["run"] == {"run_id": "x"}
    assert metrics["relocalisation"] == {"count": 0, "frames_lost": 1, "new_maps": 0}
    assert metrics["timing"]["total"]["frames"] == 20
    written = read_tum(tmp_path / "trajectory.tum")
    np.testing.assert_array_equal(written.stamps_ns, log.trajectory().stamps_ns)
    np.testing.assert_allclose(written.T_world_cam, log.trajectory().T_world_cam, atol=1e-6)


def test_the_source_statuses_give_the_skipped_frames_section(tmp_path):
    log = _log(_truth(5), lost=set(), keyframes={0}, rng=np.random.default_rng(5))
    assert log.skipped_frames() == {"total": 0, "reasons": {}}
    log.add_source_status(codec.StageStatusMessage("source", "running", 2, skipped={"corrupt": 1}))
    log.add_source_status(codec.StageStatusMessage("source", "running", 3, skipped={"corrupt": 1, "stamp_repeat": 2}))
    log.add_source_status(codec.StageStatusMessage("source", "finished", 5, skipped={"stamp_repeat": 2, "corrupt": 1}))
    assert log.source_failure is None
    write_outputs(tmp_path, log, None, EvaluationConfig())
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["skipped_frames"] == {"total": 3, "reasons": {"corrupt": 1, "stamp_repeat": 2}}
    log.add_source_status(codec.StageStatusMessage("source", "failed", 5, detail="frame 6: image x.png could not be decoded"))
    assert log.source_failure == "frame 6: image x.png could not be decoded"


def test_outputs_without_ground_truth_have_no_ate_and_no_plot(tmp_path):
    log = _log(_truth(5), lost=set(), keyframes={0}, rng=np.random.default_rng(3))
    result = write_outputs(tmp_path, log, None, EvaluationConfig())
    assert result.evaluation is None and result.evaluation_error is None
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert "ate" not in metrics and metrics["frames"] == 5
    assert not (tmp_path / "trajectory_top.png").exists()


def test_too_few_poses_give_a_reason_instead_of_an_ate(tmp_path):
    truth = _truth(6)
    log = _log(truth, lost={0, 1, 2, 3, 4}, keyframes=set(), rng=np.random.default_rng(4))
    result = write_outputs(tmp_path, log, truth, EvaluationConfig())
    assert result.evaluation is None and result.evaluation_error
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["evaluation_error"] == result.evaluation_error


def test_run_folders_are_never_reused(tmp_path):
    run_dir = prepare_run_dir(tmp_path, "r1")
    path = write_config(run_dir, RunConfig())
    assert load_run_config(path) == RunConfig()
    with pytest.raises(ConfigError, match="already holds files"):
        prepare_run_dir(tmp_path, "r1")
    with pytest.raises(ConfigError, match="key chunk"):
        prepare_run_dir(tmp_path, "a/b")


def test_monocular_runs_are_aligned_with_scale():
    assert evaluation_config_for(EvaluationConfig(), "mono").alignment == "sim3"
    assert evaluation_config_for(EvaluationConfig(), "stereo").alignment == "se3"
    assert evaluation_config_for(EvaluationConfig(alignment="none"), "mono").alignment == "none"


def test_stream_timing_spans_the_first_frame_sent_to_the_last_update_and_gives_the_realtime_factor():
    log = RunLog()
    assert log.stream_timing() == {}  # nothing arrived
    for i in range(10):  # 10 frames at 10 Hz: 1 s of data
        log.add_state(codec.TrackingStateMessage(i, i * 100_000_000, "ok", has_pose=True, timings_ms={"total": 50.0}))
        log.note_arrival(100.0 + 0.2 * i, state=True)
    log.note_arrival(102.05)  # the last map update, after the last state
    log.note_arrival(101.0)  # an earlier update arriving late does not shorten the stream
    timing = log.stream_timing()
    # first state at 100.0 s, its frame sent 50 ms before; last update at 102.05 s
    assert timing["stream_s"] == pytest.approx(2.1)
    assert timing["data_duration_s"] == pytest.approx(1.0)
    assert timing["realtime_factor"] == pytest.approx(1.0 / 2.1)


def test_a_frontend_restart_counts_the_frames_between_the_last_pose_and_the_first_after_it():
    log = RunLog()
    for i in range(12):
        posed = i < 5 or i >= 9  # frames 5..8: lost or never tracked; 9 relocalised
        log.add_state(codec.TrackingStateMessage(i, 10 * (i + 1), "ok" if posed else "lost", has_pose=posed))
    log.restarts.append({"stage": "frontend", "signal": "SIGKILL", "restart": 1, "frame": 6, "last_frame_index": 5})
    log.restarts.append({"stage": "backend", "signal": "SIGKILL", "restart": 1, "frame": 11, "last_frame_index": 10})
    frontend, backend = log.restart_events()
    assert (frontend["frames_lost"], frontend["relocalised_at"]) == (4, 9)
    assert "frames_lost" not in backend
    log.restarts.append({"stage": "frontend", "signal": "SIGKILL", "restart": 2, "frame": 12, "last_frame_index": 11})
    assert log.restart_events()[-1]["frames_lost"] is None  # never relocalised


def test_corrections_an_answer_announces_are_owed_until_they_arrive():
    # A lockstep frontend waits for them as for the answer, so the hang watch counts them as the
    # backend's work: a backend stopped between an answer and its correction is the one that hangs.
    log = RunLog()
    assert log.corrections_owed == 0
    log.add_map_update(MapUpdate(keyframe_id=0, stamp_ns=0, corrections_following=1, corrections_after_next_frame=True))
    assert log.corrections_owed == 1  # the local-mapping correction
    log.add_map_update(MapUpdate(keyframe_id=0, stamp_ns=0, kind="correction", corrections_following=2))
    assert log.corrections_owed == 2  # the two loop corrections it announced
    log.add_map_update(MapUpdate(keyframe_id=0, stamp_ns=0, kind="correction"))
    log.add_map_update(MapUpdate(keyframe_id=0, stamp_ns=0, kind="correction"))
    assert log.corrections_owed == 0
    log.add_map_update(MapUpdate(keyframe_id=1, stamp_ns=0))  # an answer with nothing to follow
    assert log.corrections_owed == 0 and log.keyframe_counts()["processed"] == 2
