"""ATE and RPE with known answers: identical, rigidly moved, scaled, offset, noisy and drifting trajectories."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from zenslam.errors import TrajectoryError
from zenslam.geometry import make_T, so3_exp
from zenslam.service.evaluation.metrics import EvaluationConfig, evaluate
from zenslam.service.evaluation.trajectory_io import read_trajectory
from zenslam.trajectory import Trajectory

EXACT_M = 1e-9  # metres: what "zero" means after an exact alignment
STEP_NS = 50_000_000  # 20 Hz
T0_NS = 1_403_715_274_312_143_104


def wandering_trajectory(rng: np.random.Generator, n: int = 60) -> Trajectory:
    """A 3D random walk with turning cameras: no alignment degeneracy."""
    p_world = np.cumsum(rng.normal(0.0, 0.5, (n, 3)), axis=0)
    poses = np.stack([make_T(so3_exp(rng.normal(0.0, 0.8, 3)), p) for p in p_world])
    return Trajectory(stamps_ns=T0_NS + STEP_NS * np.arange(n, dtype=np.int64), T_world_cam=poses)


def with_poses(traj: Trajectory, T_world_cam: np.ndarray) -> Trajectory:
    return Trajectory(stamps_ns=traj.stamps_ns.copy(), T_world_cam=T_world_cam)


def corkscrew(n: int, step_m: float, yaw_rad: float) -> Trajectory:
    """Camera moving along world z by ``step_m`` and turning about z by ``yaw_rad`` per step."""
    poses = np.stack([make_T(so3_exp([0.0, 0.0, k * yaw_rad]), [0.0, 0.0, k * step_m]) for k in range(n)])
    return Trajectory(stamps_ns=STEP_NS * np.arange(n, dtype=np.int64), T_world_cam=poses)


@pytest.mark.parametrize("alignment", ["se3", "sim3", "none"])
def test_ground_truth_against_itself_is_zero(alignment: str) -> None:
    gt = wandering_trajectory(np.random.default_rng(0))
    ev = evaluate(gt, gt, EvaluationConfig(alignment=alignment))
    assert ev.ate.rmse_m < EXACT_M and ev.ate.max_m < EXACT_M
    assert ev.rpe.trans_rmse_m < EXACT_M and ev.rpe.rot_rmse_deg < 1e-6
    assert ev.ate.matched_poses == len(gt) and ev.rpe.pairs == len(gt) - 1
    assert ev.path_length_m == pytest.approx(gt.path_length_m(), rel=1e-12)


def test_rigid_transform_vanishes_after_se3_alignment_only() -> None:
    gt = wandering_trajectory(np.random.default_rng(1))
    T_other_world = make_T(so3_exp([0.3, -1.2, 0.7]), [5.0, -3.0, 10.0])
    est = with_poses(gt, T_other_world @ gt.T_world_cam)
    aligned = evaluate(est, gt, EvaluationConfig(alignment="se3"))
    assert aligned.ate.rmse_m < EXACT_M
    assert aligned.ate.scale is None
    # The alignment found is the inverse of the applied transform.
    np.testing.assert_allclose(aligned.S_gt_est @ T_other_world, np.eye(4), atol=1e-9)
    assert evaluate(est, gt, EvaluationConfig(alignment="none")).ate.rmse_m > 1.0


def test_scaled_and_moved_estimate_needs_sim3() -> None:
    gt = wandering_trajectory(np.random.default_rng(2))
    scaled = gt.T_world_cam.copy()
    scaled[:, :3, 3] *= 2.5
    est = with_poses(gt, make_T(so3_exp([0.5, 0.1, -0.4]), [1.0, 2.0, 3.0]) @ scaled)
    sim3 = evaluate(est, gt, EvaluationConfig(alignment="sim3"))
    assert sim3.ate.rmse_m < EXACT_M
    # The scale is the factor applied to the estimate: 1 / 2.5.
    assert sim3.ate.scale == pytest.approx(0.4, rel=1e-9)
    assert sim3.rpe.trans_rmse_m < EXACT_M  # RPE runs on the scale-corrected estimate
    assert evaluate(est, gt, EvaluationConfig(alignment="se3")).ate.rmse_m > 0.5


def test_constant_offset_without_alignment() -> None:
    gt = wandering_trajectory(np.random.default_rng(3))
    shifted = gt.T_world_cam.copy()
    shifted[:, 1, 3] += 0.1
    ev = evaluate(with_poses(gt, shifted), gt, EvaluationConfig(alignment="none"))
    for value in (ev.ate.rmse_m, ev.ate.mean_m, ev.ate.median_m, ev.ate.max_m):
        assert value == pytest.approx(0.1, abs=1e-12)
    assert ev.ate.rmse_percent_of_path == pytest.approx(100 * 0.1 / ev.path_length_m, rel=1e-12)
    assert ev.rpe.trans_rmse_m < EXACT_M  # a constant offset has no relative error


def test_gaussian_noise_rmse() -> None:
    rng = np.random.default_rng(4)
    gt = wandering_trajectory(rng, n=2000)
    noisy = gt.T_world_cam.copy()
    noisy[:, :3, 3] += rng.normal(0.0, 0.01, (len(gt), 3))
    ev = evaluate(with_poses(gt, noisy), gt, EvaluationConfig(alignment="none"))
    assert ev.ate.rmse_m == pytest.approx(0.01 * np.sqrt(3.0), rel=0.05)


def test_rpe_of_constant_drift_per_step() -> None:
    gt = corkscrew(30, step_m=1.0, yaw_rad=0.05)
    est = corkscrew(30, step_m=1.01, yaw_rad=0.05 + np.deg2rad(0.1))
    ev = evaluate(est, gt, EvaluationConfig(alignment="none"))
    # Each step is 1 cm too long and turns 0.1 degrees too far.
    assert ev.rpe.trans_rmse_m == pytest.approx(0.01, abs=1e-12)
    assert ev.rpe.rot_rmse_deg == pytest.approx(0.1, abs=1e-9)
    assert ev.rpe.pairs == 29
    two = evaluate(est, gt, EvaluationConfig(alignment="none", rpe_delta=2, rpe_delta_unit="frames"))
    assert two.rpe.trans_rmse_m == pytest.approx(0.02, abs=1e-12)
    metres = evaluate(est, gt, EvaluationConfig(alignment="none", rpe_delta=5.0, rpe_delta_unit="m"))
    assert metres.rpe.trans_rmse_m == pytest.approx(0.05, abs=1e-12)
    assert metres.rpe.delta_unit == "m" and metres.rpe.pairs == 5


def test_association_within_max_difference() -> None:
    gt = wandering_trajectory(np.random.default_rng(5), n=40)
    # Every other pose, 3 ms late: 20 pairs at 1.4e18 ns, where float64 seconds would blur the stamps.
    est = Trajectory(stamps_ns=gt.stamps_ns[::2] + 3_000_000, T_world_cam=gt.T_world_cam[::2])
    ev = evaluate(est, gt)
    assert (ev.ate.matched_poses, ev.ate.estimate_poses, ev.ate.ground_truth_poses) == (20, 20, 40)
    assert ev.ate.rmse_m < EXACT_M
    late = Trajectory(stamps_ns=gt.stamps_ns + 20_000_000, T_world_cam=gt.T_world_cam)
    with pytest.raises(TrajectoryError, match="only 0 poses associate"):
        evaluate(late, gt)
    assert evaluate(late, gt, EvaluationConfig(max_time_diff_ns=21_000_000)).ate.matched_poses == 40


def test_too_few_matches_names_both_stamp_ranges() -> None:
    gt = wandering_trajectory(np.random.default_rng(6), n=10)
    est = Trajectory(stamps_ns=gt.stamps_ns[-2:], T_world_cam=gt.T_world_cam[-2:])
    with pytest.raises(TrajectoryError) as info:
        evaluate(est, gt)
    message = str(info.value)
    assert "only 2 poses associate" in message
    assert f"{gt.stamps_ns[0]} .. {gt.stamps_ns[-1]} ns" in message
    assert f"{est.stamps_ns[0]} .. {est.stamps_ns[-1]} ns" in message


def test_empty_estimate_is_an_error() -> None:
    gt = wandering_trajectory(np.random.default_rng(9), n=5)
    empty = Trajectory(stamps_ns=np.zeros(0, dtype=np.int64), T_world_cam=np.zeros((0, 4, 4)))
    with pytest.raises(TrajectoryError, match="the estimate trajectory has no poses"):
        evaluate(empty, gt)


def test_index_association_pairs_equal_frame_indices() -> None:
    gt = corkscrew(20, step_m=1.0, yaw_rad=0.05)
    indexed = Trajectory(stamps_ns=np.arange(20, dtype=np.int64), T_world_cam=gt.T_world_cam)
    est = Trajectory(stamps_ns=np.arange(5, 15, dtype=np.int64), T_world_cam=gt.T_world_cam[5:15])
    ev = evaluate(est, indexed, EvaluationConfig(association="index", alignment="none"))
    assert ev.ate.matched_poses == 10 and ev.ate.rmse_m < EXACT_M


def test_degenerate_alignment_is_an_error() -> None:
    still = Trajectory(stamps_ns=STEP_NS * np.arange(5, dtype=np.int64), T_world_cam=np.stack([np.eye(4)] * 5))
    with pytest.raises(TrajectoryError, match="sim3 alignment of 5 matched poses failed"):
        evaluate(still, still, EvaluationConfig(alignment="sim3"))


def test_inputs_are_not_modified() -> None:
    gt = wandering_trajectory(np.random.default_rng(7))
    est = with_poses(gt, make_T(so3_exp([0.1, 0.2, 0.3]), [1.0, 0.0, 0.0]) @ gt.T_world_cam)
    before = est.T_world_cam.copy()
    evaluate(est, gt, EvaluationConfig(alignment="sim3"))
    np.testing.assert_array_equal(est.T_world_cam, before)


def test_to_json_has_the_documented_keys() -> None:
    gt = wandering_trajectory(np.random.default_rng(8))
    doc = evaluate(gt, gt, EvaluationConfig(alignment="sim3")).to_json()
    assert set(doc) == {"ate", "rpe", "path_length_m"}
    ate_keys = {"rmse_m", "mean_m", "median_m", "max_m", "rmse_percent_of_path", "alignment", "scale", "matched_poses"}
    assert ate_keys <= set(doc["ate"])
    assert {"delta", "delta_unit", "trans_rmse_m", "rot_rmse_deg"} <= set(doc["rpe"])
    assert doc["ate"]["alignment"] == "sim3" and doc["ate"]["scale"] == pytest.approx(1.0)


def test_real_kitti_ground_truth_against_itself(kitti_root: Path) -> None:
    gt = read_trajectory(kitti_root / "poses" / "06.txt")
    ev = evaluate(gt, gt, EvaluationConfig(association="index"))
    assert ev.ate.matched_poses == 51 and ev.ate.rmse_m < EXACT_M
    assert ev.path_length_m == pytest.approx(59.86, abs=0.01)


def test_real_euroc_ground_truth_against_itself(euroc_micro: Path) -> None:
    gt = read_trajectory(euroc_micro / "groundtruth_cam0.csv")
    ev = evaluate(gt, gt)
    assert ev.ate.matched_poses == 74 and ev.ate.rmse_m < EXACT_M
