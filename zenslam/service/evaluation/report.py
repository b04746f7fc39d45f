"""metrics.json, the evaluation results file that scripts and CI read, and its text summary.

Format (a UTF-8 JSON object; keys are stable, new keys may be added, none renamed)::

    {
      "ate": {
        "rmse_m": float,              # position error after alignment, metres (also mean_m, median_m, max_m)
        "mean_m": float,
        "median_m": float,
        "max_m": float,
        "rmse_percent_of_path": float | null,   # 100 * rmse_m / path_length_m; null for a zero-length path
        "alignment": "se3" | "sim3" | "none",
        "scale": float | null,        # sim3 only: factor applied to the estimate (estimate 2.5x too big -> 0.4)
        "matched_poses": int,         # poses associated with ground truth and compared
        "estimate_poses": int,
        "ground_truth_poses": int
      },
      "rpe": {
        "delta": float,               # pair spacing, in delta_unit
        "delta_unit": "frames" | "m",
        "trans_rmse_m": float,        # RMSE of the relative translation error, metres
        "rot_rmse_deg": float,        # RMSE of the relative rotation angle, degrees
        "pairs": int
      },
      "path_length_m": float,         # length of the matched ground truth, metres
      "loops": {                      # zenslam run and zenslam eval; see zenslam.service.evaluation.loops
        "revisit_error_m": float | null,   # relative pose error (translation) from the first pose to where
                                      # the ground truth first comes back to it; null: no return / no truth
        "candidates": int,            # zenslam run: loop candidates verified (backend/loop messages)
        "accepted": int,
        "rejected": int,
        "refused": int,               # rejected after verification (drift budget, pose graph)
        "false_accepted": int,        # with ground truth: accepted loops off the truth by > 0.3 m or 5 deg
        "accepted_loops": [...],      # with ground truth: each accepted loop's error against it
        "refused_loops": [...],       # the same for each refused loop, with the reason
        ...                           # (see zenslam.service.evaluation.loop_acceptance)
      },
      "relocalisation": {"count": int, "frames_lost": int, "new_maps": int},   # zenslam run
      "run": {"run_id": str, "source": str, "mode": str, "completed": bool,      # zenslam run
              "stream_s": float,          # first frame sent to the last map update received (s)
              "data_duration_s": float,   # the frames' stamp span plus one period (s)
              "realtime_factor": float,   # data_duration_s / stream_s (> 1: faster than the camera)
              "environment": {"python": str, "machine": str, "platform": str, "cpu_count": int,
                              "libraries": {str: str}}},  # installed versions (zenslam.runtime.environment)
      ...                             # extra top-level sections from the caller, e.g. zenslam run's
                                      # "timing", "frames", "lost_frames"
    }

A run without ground truth writes only its extra sections (no "ate", "rpe", "path_length_m").
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from zenslam.errors import TrajectoryError
from zenslam.service.evaluation.metrics import Evaluation

logger = logging.getLogger(__name__)

METRICS_FILENAME = "metrics.json"


def write_metrics(path: str | Path, evaluation: Evaluation | None, **extra: Any) -> Path:
    """Write ``metrics.json`` at ``path``: the evaluation's sections plus ``extra`` top-level sections.

    ``extra`` values must be JSON-serialisable (numpy scalars and arrays are converted). Raises
    ValueError when an extra section would overwrite an evaluation section (a programming error).
    """
    path = Path(path)
    content: dict[str, Any] = evaluation.to_json() if evaluation is not None else {}
    clashes = sorted(set(content) & set(extra))
    if clashes:
        raise ValueError(f"extra metrics sections {clashes} would overwrite the evaluation's; rename them")
    content.update(extra)
    text = json.dumps(content, indent=2, default=_to_builtin, allow_nan=False) + "\n"
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)  # readers never see a half-written file
    except OSError as exc:
        raise TrajectoryError(f"cannot write metrics file {path}: {exc}; check the output folder") from exc
    logger.debug("wrote %s", path)
    return path


def read_metrics(path: str | Path) -> dict[str, Any]:
    """Read a ``metrics.json`` back as a dict."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise TrajectoryError(f"metrics file {path} does not exist; check the path") from exc
    except (OSError, ValueError) as exc:
        raise TrajectoryError(f"cannot read metrics file {path}: {exc}") from exc


def format_summary(evaluation: Evaluation) -> str:
    """A few lines of the figures for people: matched poses, ATE, RPE."""
    ate, rpe = evaluation.ate, evaluation.rpe
    percent = f"{ate.rmse_percent_of_path:.3f} % of " if ate.rmse_percent_of_path is not None else ""
    scale = f", scale {ate.scale:.6f}" if ate.scale is not None else ""
    delta = f"{rpe.delta:g} {rpe.delta_unit}"
    return "\n".join(
        [
            f"matched poses  {ate.matched_poses} (estimate {ate.estimate_poses}, ground truth {ate.ground_truth_poses})",
            f"ATE ({ate.alignment}{scale})  rmse {ate.rmse_m:.6f} m, mean {ate.mean_m:.6f} m, "
            f"median {ate.median_m:.6f} m, max {ate.max_m:.6f} m ({percent}{evaluation.path_length_m:.3f} m path)",
            f"RPE ({delta}, {rpe.pairs} pairs)  trans rmse {rpe.trans_rmse_m:.6f} m, rot rmse {rpe.rot_rmse_deg:.6f} deg",
        ]
    )


def _to_builtin(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")
