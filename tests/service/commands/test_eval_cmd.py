"""``zenslam eval``: exit codes, metrics.json, the plot, and the console script."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from zenslam.geometry import make_T, so3_exp
from zenslam.service.cli import main
from zenslam.service.evaluation.trajectory_io import write_euroc, write_kitti, write_tum
from zenslam.trajectory import Trajectory

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
NOISE_M = 0.02  # per-axis position noise of the synthetic estimate


def write_pair(folder: Path) -> tuple[Path, Path]:
    """A TUM estimate (rigidly moved ground truth plus noise) and an EuRoC ground truth."""
    rng = np.random.default_rng(0)
    n = 200
    p_world = np.cumsum(rng.normal(0.0, 0.3, (n, 3)), axis=0)
    gt = Trajectory(
        stamps_ns=1_403_715_274_312_143_104 + 50_000_000 * np.arange(n, dtype=np.int64),
        T_world_cam=np.stack([make_T(so3_exp(rng.normal(0.0, 0.5, 3)), p) for p in p_world]),
    )
    est_poses = make_T(so3_exp([0.2, -0.4, 1.0]), [3.0, -1.0, 0.5]) @ gt.T_world_cam
    est_poses[:, :3, 3] += rng.normal(0.0, NOISE_M, (n, 3))
    est = Trajectory(stamps_ns=gt.stamps_ns + 2_000_000, T_world_cam=est_poses)
    return write_tum(folder / "run" / "trajectory.txt", est), write_euroc(folder / "gt" / "data.csv", gt)


def test_eval_writes_metrics_and_plot(tmp_path: Path) -> None:
    est, gt = write_pair(tmp_path)
    out = tmp_path / "out"
    assert main(["eval", str(est), str(gt), "--output", str(out)]) == 0
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["ate"]["alignment"] == "se3" and doc["ate"]["matched_poses"] == 200
    assert doc["ate"]["rmse_m"] == pytest.approx(NOISE_M * np.sqrt(3.0), rel=0.15)
    assert doc["rpe"]["delta"] == 1 and doc["rpe"]["delta_unit"] == "frames"
    assert doc["path_length_m"] > 10.0
    png = (out / "trajectory_top.png").read_bytes()
    assert len(png) > 0 and png.startswith(PNG_SIGNATURE)


def test_eval_options_and_default_output_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    est, gt = write_pair(tmp_path)
    argv = ["eval", str(est), str(gt), "--align", "sim3", "--format-est", "tum", "--format-gt", "euroc"]
    argv += ["--rpe-delta-frames", "5"]
    assert main(argv) == 0
    doc = json.loads((est.parent / "metrics.json").read_text())
    assert doc["ate"]["alignment"] == "sim3" and doc["ate"]["scale"] == pytest.approx(1.0, abs=0.01)
    assert doc["rpe"]["delta"] == 5 and doc["rpe"]["pairs"] == 39
    assert (est.parent / "trajectory_top.png").is_file()
    printed = capsys.readouterr().out
    assert "ATE (sim3" in printed and "matched poses  200" in printed
    assert main(["eval", str(est), str(gt), "--delta-m", "2.0", "--output", str(tmp_path / "m")]) == 0
    assert json.loads((tmp_path / "m" / "metrics.json").read_text())["rpe"]["delta_unit"] == "m"


def test_eval_kitti_pair_associates_by_index(tmp_path: Path) -> None:
    poses = np.stack([make_T(np.eye(3), [0.1 * np.sin(k), 0.0, float(k)]) for k in range(30)])
    gt = write_kitti(tmp_path / "gt.txt", Trajectory(stamps_ns=np.arange(30, dtype=np.int64), T_world_cam=poses))
    est = write_kitti(tmp_path / "est.txt", Trajectory(stamps_ns=np.arange(20, dtype=np.int64), T_world_cam=poses[:20]))
    assert main(["eval", str(est), str(gt), "--align", "none"]) == 0
    doc = json.loads((tmp_path / "metrics.json").read_text())
    assert doc["ate"]["matched_poses"] == 20 and doc["ate"]["rmse_m"] < 1e-9


def test_eval_bad_input_exits_2(tmp_path: Path) -> None:
    est, _ = write_pair(tmp_path)
    assert main(["eval", str(est), str(tmp_path / "missing.csv")]) == 2
    with pytest.raises(SystemExit) as info:
        main(["eval", str(est), str(est), "--delta-m", "1", "--rpe-delta-frames", "2"])
    assert info.value.code == 2


def test_eval_real_kitti_ground_truth(kitti_root: Path, tmp_path: Path) -> None:
    gt = kitti_root / "poses" / "06.txt"
    assert main(["eval", str(gt), str(gt), "--output", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "metrics.json").read_text())
    assert doc["ate"]["matched_poses"] == 51 and doc["ate"]["rmse_m"] < 1e-9


def test_console_script(tmp_path: Path) -> None:
    script = Path(sys.executable).parent / "zenslam"
    if not script.exists():
        pytest.skip(f"console script not installed beside {sys.executable}")
    est, gt = write_pair(tmp_path)
    out = tmp_path / "cli"
    done = subprocess.run(
        [str(script), "eval", str(est), str(gt), "--output", str(out)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert "ATE (se3)" in done.stdout
    assert json.loads((out / "metrics.json").read_text())["ate"]["matched_poses"] == 200
