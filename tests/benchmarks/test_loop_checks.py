"""benchmarks/loop_checks.py's figures of one verified loop: where the loop puts the current keyframe
(from the published transform and scale) and that move as a share of the keyframes' path."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from zenslam.geometry import invert_T, make_T, so3_exp
from zenslam.schemas import codec

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def script():
    sys.path.insert(0, str(BENCHMARKS))  # the script imports backend_quality beside it
    try:
        spec = importlib.util.spec_from_file_location("loop_checks", BENCHMARKS / "loop_checks.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return module


@pytest.mark.parametrize("scale", [1.0, 0.8])
def test_a_loop_is_placed_and_measured_against_the_path(script, scale: float) -> None:
    """Keyframes 0-10 along x, 1 m apart; keyframe 10 is truly back at keyframe 0's place, 1 m to its
    side. A loop whose transform says so (p_cur = s R p_loop + t, the map's unit 1 / s of the loop
    keyframe's) moves keyframe 10 from (10, 0, 0) to (0, 1, 0)."""
    poses = {k: make_T(np.eye(3), [float(k), 0.0, 0.0]) for k in range(10)}
    T_world_cur_true = make_T(so3_exp(np.array([0.0, 0.3, 0.0])), [0.0, 1.0, 0.0])
    T_cur_loop = invert_T(T_world_cur_true) @ poses[0]  # rigid, in the loop keyframe's units
    T_cur_loop[:3, 3] *= scale  # in the current keyframe's units: p_cur = s R p_loop + t
    loop = codec.LoopMessage(
        keyframe_id=10, stamp_ns=10, loop_keyframe_id=0, loop_stamp_ns=0, accepted=False, reason="pose graph",
        T_world_cur_before=make_T(np.eye(3), [10.0, 0.0, 0.0]), T_world_loop=poses[0], T_cur_loop=T_cur_loop,
        scale=scale, inliers=50,
    )  # fmt: skip
    corrected = script.corrected_pose(loop)
    np.testing.assert_allclose(corrected[:3, 3], [0.0, 1.0, 0.0], atol=1e-12)
    check, _ = script._check(loop, poses)
    assert check["outcome"] == "R" and check["moved"] == pytest.approx(np.hypot(10.0, 1.0), abs=1e-4)
    assert check["share_of_path"] == pytest.approx(np.hypot(10.0, 1.0) / 10.0, abs=1e-5)  # path 0 -> 10: 10 m
