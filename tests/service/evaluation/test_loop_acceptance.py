"""The loops section of metrics.json: counts and false accepts judged against ground truth."""

from __future__ import annotations

import numpy as np

from zenslam.geometry import invert_T, make_T, so3_exp
from zenslam.schemas import codec
from zenslam.service.evaluation.loop_acceptance import acceptance_counts
from zenslam.trajectory import Trajectory

STEP_NS = 100_000_000


def truth() -> Trajectory:
    poses = [make_T(so3_exp(np.array([0.0, 0.1 * i, 0.0])), np.array([float(i), 0.0, 0.0])) for i in range(20)]
    return Trajectory(np.arange(20, dtype=np.int64) * STEP_NS, np.stack(poses))


def loop(
    cur: int, old: int, T_cur_loop: np.ndarray, accepted: bool = True, reason: str = "too few inliers", inliers: int = 0
) -> codec.LoopMessage:
    return codec.LoopMessage(
        keyframe_id=cur, stamp_ns=cur * STEP_NS, loop_keyframe_id=old, loop_stamp_ns=old * STEP_NS, accepted=accepted,
        reason="" if accepted else reason, T_world_cur_before=np.eye(4), T_world_loop=np.eye(4), T_cur_loop=T_cur_loop,
        inliers=inliers,
    )


def test_a_loop_matching_the_truth_is_true_and_one_off_by_half_a_metre_is_false() -> None:
    gt = truth()
    T_true = invert_T(gt.T_world_cam[15]) @ gt.T_world_cam[2]
    off = invert_T(gt.T_world_cam[16]) @ gt.T_world_cam[3]
    off[:3, 3] += [0.5, 0.0, 0.0]
    loops = [loop(15, 2, T_true), loop(16, 3, off), loop(17, 4, np.eye(4), accepted=False)]
    section = acceptance_counts(loops, gt)
    assert (section["candidates"], section["accepted"], section["rejected"]) == (3, 2, 1)
    assert section["false_accepted"] == 1
    assert section["accepted_loops"][0]["error_m"] < 1e-9 and abs(section["accepted_loops"][1]["error_m"] - 0.5) < 1e-9


def test_without_ground_truth_only_counts_are_reported() -> None:
    assert acceptance_counts([loop(15, 2, np.eye(4))], None) == {"candidates": 1, "accepted": 1, "rejected": 0, "refused": 0}


def test_a_loop_refused_after_verification_is_judged_against_the_truth() -> None:
    """The drift budget refused a loop 0.5 m off the truth (it kept a wrong loop out); a candidate that
    failed verification (no inliers, no transform) is rejected but not judged."""
    gt = truth()
    off = invert_T(gt.T_world_cam[16]) @ gt.T_world_cam[3]
    off[:3, 3] += [0.0, 0.5, 0.0]
    budget = "drift budget: the loop moves the keyframe 1.200 m, 9.0% of the 13.00 m path (budget 5%)"
    loops = [loop(16, 3, off, accepted=False, reason=budget, inliers=80), loop(17, 4, np.eye(4), accepted=False)]
    section = acceptance_counts(loops, gt)
    assert (section["rejected"], section["refused"], section["false_accepted"]) == (2, 1, 0)
    (refused,) = section["refused_loops"]
    assert (refused["keyframe_id"], refused["loop_keyframe_id"], refused["inliers"], refused["reason"]) == (16, 3, 80, budget)
    assert abs(refused["error_m"] - 0.5) < 1e-9 and refused["error_deg"] < 1e-6


def test_a_monocular_loop_is_judged_in_metres_through_the_maps_scale() -> None:
    gt = truth()
    in_units = invert_T(gt.T_world_cam[15]) @ gt.T_world_cam[2]
    in_units[:3, 3] /= 4.0  # a map whose unit is 4 m
    assert acceptance_counts([loop(15, 2, in_units)], gt)["false_accepted"] == 1
    section = acceptance_counts([loop(15, 2, in_units)], gt, metres_per_unit=4.0)
    assert section["false_accepted"] == 0 and section["accepted_loops"][0]["error_m"] < 1e-9
