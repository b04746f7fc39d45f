"""metrics.json: the evaluation sections, extra sections, and the text summary."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from zenslam.errors import TrajectoryError
from zenslam.geometry import make_T
from zenslam.service.evaluation.metrics import EvaluationConfig, evaluate
from zenslam.service.evaluation.report import format_summary, read_metrics, write_metrics
from zenslam.trajectory import Trajectory


def offset_evaluation():
    """An estimate 0.1 m off along x, no alignment: ATE 0.1 m over a 9 m path."""
    gt = Trajectory(
        stamps_ns=np.arange(10, dtype=np.int64) * 100_000_000,
        T_world_cam=np.stack([make_T(np.eye(3), [0.0, 0.0, float(k)]) for k in range(10)]),
    )
    est_poses = gt.T_world_cam.copy()
    est_poses[:, 0, 3] += 0.1
    est = Trajectory(stamps_ns=gt.stamps_ns, T_world_cam=est_poses)
    return evaluate(est, gt, EvaluationConfig(alignment="none"))


def test_write_metrics_with_extra_sections(tmp_path: Path) -> None:
    timing = {"frontend": {"mean_ms": np.float64(12.5), "max_ms": 30.0}}
    path = write_metrics(
        tmp_path / "out" / "metrics.json", offset_evaluation(), timing=timing, frames=np.int64(10), lost_frames=[]
    )
    doc = json.loads(path.read_text())
    assert doc["ate"]["rmse_m"] == pytest.approx(0.1, abs=1e-12)
    assert doc["ate"]["alignment"] == "none" and doc["ate"]["scale"] is None
    assert doc["rpe"]["delta_unit"] == "frames"
    assert doc["path_length_m"] == pytest.approx(9.0)
    assert doc["timing"]["frontend"]["mean_ms"] == 12.5 and doc["frames"] == 10 and doc["lost_frames"] == []
    assert read_metrics(path) == doc
    assert not (tmp_path / "out" / "metrics.json.tmp").exists()


def test_write_metrics_without_evaluation(tmp_path: Path) -> None:
    doc = read_metrics(write_metrics(tmp_path / "metrics.json", None, frames=3))
    assert doc == {"frames": 3}


def test_extra_section_cannot_replace_evaluation(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="'ate'"):
        write_metrics(tmp_path / "metrics.json", offset_evaluation(), ate={})


def test_read_missing_metrics(tmp_path: Path) -> None:
    with pytest.raises(TrajectoryError, match="metrics.json does not exist"):
        read_metrics(tmp_path / "metrics.json")


def test_summary_shows_the_figures() -> None:
    text = format_summary(offset_evaluation())
    assert "matched poses  10" in text
    assert "rmse 0.100000 m" in text
    assert "1.111 % of 9.000 m path" in text
