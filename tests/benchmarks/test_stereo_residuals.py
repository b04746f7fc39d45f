"""benchmarks/stereo_residuals.py's measure: on a window whose right images carry a known disparity
error, the residuals it reports are that error, across the image as it varies."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from zenslam.backend.ba_problem import BAProblem, BAResult
from zenslam.camera import PinholeCalibration
from zenslam.geometry import make_T

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "stereo_residuals.py"
CAL = PinholeCalibration(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480, baseline_m=0.1)


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("stereo_residuals", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _window(disparity_error) -> tuple[BAProblem, BAResult]:
    """Three keyframes along x seeing 200 points in front of them, every observation exact but for
    the right image's u, which makes each disparity smaller by ``disparity_error(u)`` px; the
    result is the truth, every observation an inlier. The first point is seen by one keyframe only."""
    rng = np.random.default_rng(3)
    p_world = np.column_stack([rng.uniform(-3, 3, 200), rng.uniform(-2, 2, 200), rng.uniform(4, 12, 200)])
    T_world_cam = np.stack([make_T(np.eye(3), [0.2 * k, 0.0, 0.0]) for k in range(3)])
    obs_kf, obs_pt = np.meshgrid(np.arange(3), np.arange(200), indexing="ij")
    obs_kf, obs_pt = obs_kf.ravel(), obs_pt.ravel()
    single = (obs_pt == 0) & (obs_kf > 0)
    obs_kf, obs_pt = obs_kf[~single], obs_pt[~single]
    p_cam = p_world[obs_pt] - T_world_cam[obs_kf, :3, 3]
    u = CAL.fx * p_cam[:, 0] / p_cam[:, 2] + CAL.cx
    v = CAL.fy * p_cam[:, 1] / p_cam[:, 2] + CAL.cy
    right_u = u - CAL.bf / p_cam[:, 2] + disparity_error(u)
    problem = BAProblem(
        calibration=CAL, keyframe_ids=np.arange(3), T_world_cam=T_world_cam, fixed=np.array([True, False, False]),
        point_ids=np.arange(200), p_world=p_world, obs_keyframe=obs_kf, obs_point=obs_pt,
        obs_px=np.column_stack([u, v]), obs_right_u=right_u, obs_inv_sigma2=np.ones(len(u)),
    )  # fmt: skip
    result = BAResult(T_world_cam, p_world, np.ones(len(u), dtype=bool), np.zeros(0, dtype=np.int64))
    return problem, result


def test_a_constant_disparity_error_is_the_median_residual(script):
    r = script.residuals([_window(lambda u: np.full_like(u, 0.07))], min_observations=3)
    assert len(r["residual"]) == 3 * 199  # the point seen once is left out
    assert np.median(r["residual"]) == pytest.approx(0.07, abs=1e-9)


def test_a_disparity_error_across_the_image_shows_by_column(script):
    r = script.residuals([_window(lambda u: np.where(u < CAL.cx, 0.4, 0.0))], min_observations=2)
    rows = script.medians_by(r["residual"], r["u"], [-1e9, CAL.cx, 1e9])
    assert [row["median_px"] for row in rows] == pytest.approx([0.4, 0.0], abs=1e-9)
    assert sum(row["n"] for row in rows) == len(r["residual"])
