"""The revisit error of metrics.json ``loops``: revisits found from the ground truth, known drifts measured exactly."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from zenslam.geometry import make_T, so3_exp
from zenslam.service.evaluation.loops import loops_section, relative_pose_error, revisit_indices
from zenslam.service.evaluation.metrics import EvaluationConfig, evaluate
from zenslam.trajectory import Trajectory

STEP_NS = 100_000_000
T0_NS = 1_700_000_000_000_000_000


def circle_laps(per_lap: int, laps: int, radius_m: float = 5.0, extra: int = 0) -> Trajectory:
    """Counter-clockwise laps of a horizontal circle centred on the origin, camera looking along the path,
    ``per_lap`` frames per lap (frame per_lap * k is back at the start), plus ``extra`` frames."""
    n = per_lap * laps + 1 + extra
    angle = 2.0 * math.pi * np.arange(n) / per_lap
    poses = []
    for a in angle:
        R_world_body = so3_exp([0.0, 0.0, a + math.pi / 2])  # body x along the tangent
        R_body_cam = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
        poses.append(make_T(R_world_body @ R_body_cam, [radius_m * math.cos(a), radius_m * math.sin(a), 1.4]))
    return Trajectory(T0_NS + STEP_NS * np.arange(n, dtype=np.int64), np.stack(poses))


def with_world_drift(truth: Trajectory, drift: Callable[[int], np.ndarray]) -> Trajectory:
    """The truth with frame k's pose premultiplied by ``drift(k)`` (a 4x4 world-frame error growing with k)."""
    poses = np.stack([drift(k) @ T for k, T in enumerate(truth.T_world_cam)])
    return Trajectory(truth.stamps_ns.copy(), poses)


def test_revisits_are_the_returns_to_the_start_one_per_lap() -> None:
    truth = circle_laps(per_lap=100, laps=3)
    assert revisit_indices(truth.T_world_cam[:, :3, 3]) == [100, 200, 300]


def test_the_closest_pose_of_a_return_is_the_revisit() -> None:
    truth = circle_laps(per_lap=97, laps=2, radius_m=10.0)
    p = truth.T_world_cam[:, :3, 3].copy()
    p[97] += [0.3, 0.0, 0.0]  # the lap's end frame is 0.3 m off; its neighbour 98 comes closer
    p[98] = p[0] + [0.05, 0.0, 0.0]
    assert revisit_indices(p, radius_m=1.0) == [98, 194]


@pytest.mark.parametrize(
    "p_world",
    [
        np.zeros((50, 3)),  # a still camera
        np.column_stack([np.linspace(0.0, 30.0, 50), np.zeros(50), np.zeros(50)]),  # a straight drive
        np.column_stack([0.3 * np.sin(np.linspace(0, 6, 50)), np.zeros(50), np.zeros(50)]),  # never beyond the radius
    ],
)
def test_paths_that_never_go_away_and_come_back_have_no_revisit(p_world: np.ndarray) -> None:
    assert revisit_indices(p_world, radius_m=1.0) == []


def test_a_known_translation_drift_is_the_revisit_error_whatever_the_alignment() -> None:
    truth = circle_laps(per_lap=80, laps=2)
    drift_m_per_frame = 0.002  # world x error growing by 2 mm a frame: 16 cm at the first revisit
    estimate = with_world_drift(truth, lambda k: make_T(np.eye(3), [drift_m_per_frame * k, 0.0, 0.0]))
    for alignment in ("se3", "none"):
        evaluation = evaluate(estimate, truth, EvaluationConfig(alignment=alignment))
        loops = loops_section(evaluation, evaluation)
        assert loops["revisit_error_m"] == pytest.approx(0.16, abs=1e-9)
        assert loops["revisit_rotation_error_deg"] == pytest.approx(0.0, abs=1e-6)
        assert loops["revisit_stamp_ns"] == T0_NS + 80 * STEP_NS
        assert [r["error_m"] for r in loops["revisits"]] == pytest.approx([0.16, 0.32], abs=1e-9)


def test_a_known_heading_drift_gives_the_chord_error() -> None:
    # Rotating the world about the circle's centre (z axis) by theta moves the start point by 2 r sin(theta / 2).
    truth = circle_laps(per_lap=60, laps=2, radius_m=5.0)
    rad_per_frame = math.radians(0.05)
    estimate = with_world_drift(truth, lambda k: make_T(so3_exp([0.0, 0.0, rad_per_frame * k]), np.zeros(3)))
    loops = loops_section(evaluate(estimate, truth, EvaluationConfig(alignment="se3")))
    theta = 60 * rad_per_frame
    assert loops["revisit_error_m"] == pytest.approx(2 * 5.0 * math.sin(theta / 2), rel=1e-9)
    assert loops["revisit_rotation_error_deg"] == pytest.approx(3.0, rel=1e-9)


def test_monocular_scale_is_taken_from_the_sim3_alignment() -> None:
    truth = circle_laps(per_lap=50, laps=1)
    scaled = Trajectory(truth.stamps_ns.copy(), truth.T_world_cam.copy())
    scaled.T_world_cam[:, :3, 3] *= 0.4  # an exact trajectory at the wrong scale
    scaled.T_world_cam[25:, :3, 3] += [0.01, 0.0, 0.0]  # and 1 cm off (at that scale) from the second half on
    loops = loops_section(evaluate(scaled, truth, EvaluationConfig(alignment="sim3")))
    assert loops["revisit_error_m"] == pytest.approx(0.01 / 0.4, rel=0.05)


def test_without_a_return_or_without_truth_the_errors_are_null() -> None:
    truth = Trajectory(
        T0_NS + STEP_NS * np.arange(30, dtype=np.int64),
        np.stack([make_T(np.eye(3), [0.5 * k, 0.1 * k, 0.0]) for k in range(30)]),
    )
    section = loops_section(evaluate(truth, truth))
    assert section["revisit_error_m"] is None and section["revisit_error_tracked_m"] is None
    assert section["revisits"] == []
    assert loops_section(None)["revisit_error_m"] is None


def test_relative_pose_error_is_zero_for_a_rigidly_moved_estimate() -> None:
    truth = circle_laps(per_lap=40, laps=1)
    moved = make_T(so3_exp([0.3, -0.2, 1.0]), [4.0, -2.0, 7.0]) @ truth.T_world_cam
    trans_m, rot_deg = relative_pose_error(truth.T_world_cam, moved, 0, 40)
    assert trans_m == pytest.approx(0.0, abs=1e-9) and rot_deg == pytest.approx(0.0, abs=1e-6)
