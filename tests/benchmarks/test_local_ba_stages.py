"""benchmarks/local_ba.py --stages: the stages of one solve are measured on the window asked for."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from zenslam.backend.local_ba import LocalBAConfig

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "local_ba.py"


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("local_ba_benchmark", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


def test_solver_stages_count_the_windows_landmarks_and_observations(script):
    spec = script.WindowSpec("tiny", script.ROOM, 4, 120, 400, 1, 0.15, False, (1.5, 6.0), 4.0)
    problem = script.make_window(spec, 0).problem
    stages = script.solver_stages(problem, LocalBAConfig())
    assert stages["landmarks"] == len(problem.point_ids)
    assert stages["observation_factors"] == len(problem.obs_point)
    for key in ("build_ms", "linearize_ms", "eliminate_landmarks_ms", "eliminate_poses_ms", "error_ms", "solve_ms"):
        assert stages[key] >= 0.0, key
    assert stages["eliminate_us_per_landmark"] == pytest.approx(1e3 * stages["eliminate_landmarks_ms"] / stages["landmarks"])
    assert 1 <= stages["solve_iterations"] <= LocalBAConfig().robust_iterations + LocalBAConfig().refine_iterations
