"""Where local BA leaves the stereo measurements: disparity residuals across the image, a calibration check.

Runs the frontend and the backend in one process in lockstep order (as ``backend_quality.py``) on
one clip and keeps every local BA window with its result (a recording bundle adjuster around the
real one). For each inlier stereo observation of a point with at least ``--min-observations``
inlier observations in its window (its position set by several views, not by this disparity
alone) the residual is the disparity the optimised point and pose predict minus the measured one
(level-0 px; positive: the measurement is too small, the point looks farther than the map puts
it). Printed and written: the median residual over all, and by image column band, row band,
pyramid level and measured disparity.

A well-calibrated rig leaves medians near 0 everywhere. One constant across the image is a
principal-point offset between the rectified images (Middlebury's ``doffs``,
``frontend.stereo.disparity_offset_px``); medians that change across the image are a calibration
error of another kind (distortion left by the rectification, a focal length), which no offset
corrects.

Run: ``.venv/bin/python benchmarks/stereo_residuals.py [--data ../shared/data] [--clip kitti]
[--offset PX]`` (writes benchmarks/results/stereo_residuals.json).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
from pathlib import Path

import numpy as np

from zenslam.backend.ba_problem import BAProblem, BAResult
from zenslam.backend.config import BackendConfig
from zenslam.backend.node import BackendNode
from zenslam.frontend.node import keyframe_message
from zenslam.frontend.pipeline import FrontendConfig, FrontendPipeline
from zenslam.schemas import codec

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "stereo_residuals.json"


class RecordingAdjuster:
    """The local bundle adjuster, keeping every window it solves and its result."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.windows: list[tuple[BAProblem, BAResult]] = []

    def optimize(self, problem: BAProblem) -> BAResult:
        result = self.inner.optimize(problem)
        self.windows.append((problem, result))
        return result


def open_clip(data: Path, clip: str):
    if clip == "kitti":
        from zenslam.service.sources.kitti import KittiSource

        return KittiSource(data / "kitti_odometry" / "sequences" / "06")
    if clip == "euroc":
        from zenslam.service.sources.euroc import EurocSource

        return EurocSource(data / "euroc" / "V1_01_easy_micro")
    from zenslam.service.sources.synthetic import SyntheticSource, scene_config

    return SyntheticSource(scene_config(clip, sensor="stereo"))


def lockstep_windows(source, frontend_config: FrontendConfig) -> list[tuple[BAProblem, BAResult]]:
    """Track every frame, each keyframe mapped and its updates applied before the next frame."""
    pipeline = FrontendPipeline(frontend_config, source.calibration, source.sensor)
    backend = BackendNode.from_config(BackendConfig())
    recorder = RecordingAdjuster(backend.mapper.bundle_adjuster)
    backend.mapper.bundle_adjuster = recorder
    try:
        for frame in source:
            out = pipeline.step(frame.index, frame.stamp_ns, frame.left, right=frame.right, depth_m=frame.depth_m)
            for keyframe in out.keyframes_made:
                message = codec.decode_keyframe(codec.encode_keyframe(keyframe_message(keyframe, source.calibration, source.sensor)))
                for update in backend.step(message).updates:
                    pipeline.apply_map_update(update)
    finally:
        backend.close()
    return recorder.windows


def residuals(windows: list[tuple[BAProblem, BAResult]], min_observations: int) -> dict[str, np.ndarray]:
    """Per kept observation: residual (predicted - measured disparity, px), measured disparity, u, v and level."""
    columns: dict[str, list[np.ndarray]] = {name: [] for name in ("residual", "disparity", "u", "v", "level")}
    for problem, result in windows:
        inlier = np.asarray(result.inlier_obs, dtype=bool)
        stereo = np.isfinite(problem.obs_right_u)
        if problem.obs_disparity_sigma is not None:
            stereo &= problem.obs_disparity_sigma == 0  # RGB-D's virtual right u is not a disparity measurement
        seen = np.bincount(problem.obs_point[inlier], minlength=len(problem.point_ids))
        kept = inlier & stereo & (seen[problem.obs_point] >= min_observations)
        T = result.T_world_cam[problem.obs_keyframe[kept]]
        p_world = result.p_world[problem.obs_point[kept]]
        p_cam = np.einsum("nji,nj->ni", T[:, :3, :3], p_world - T[:, :3, 3])
        measured = problem.obs_px[kept, 0] - problem.obs_right_u[kept]
        columns["residual"].append(problem.calibration.bf / p_cam[:, 2] - measured)
        columns["disparity"].append(measured)
        columns["u"].append(problem.obs_px[kept, 0])
        columns["v"].append(problem.obs_px[kept, 1])
        scale2 = 1.0 / problem.obs_inv_sigma2[kept]  # scale_factor ** (2 * level)
        columns["level"].append(np.rint(0.5 * np.log(scale2) / np.log(1.2)).astype(int))
    return {name: np.concatenate(parts) if parts else np.zeros(0) for name, parts in columns.items()}


def medians_by(values: np.ndarray, key: np.ndarray, edges: list[float]) -> list[dict]:
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (key >= lo) & (key < hi)
        if sel.any():
            rows.append({"from": lo, "to": hi, "n": int(sel.sum()), "median_px": float(np.median(values[sel]))})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="benchmark clips root")
    parser.add_argument("--clip", default="kitti", help="kitti, euroc, or a synthetic scene (loop, figure_eight, ...)")
    parser.add_argument("--offset", type=float, default=0.0, help="frontend.stereo.disparity_offset_px for the run (px)")
    parser.add_argument("--min-observations", type=int, default=3, help="inlier observations a point needs in its window")
    args = parser.parse_args()
    source = open_clip(args.data, args.clip)
    config = FrontendConfig()
    config = dataclasses.replace(config, stereo=dataclasses.replace(config.stereo, disparity_offset_px=args.offset))
    windows = lockstep_windows(source, config)
    r = residuals(windows, args.min_observations)
    width, height = source.calibration.width, source.calibration.height
    report = {
        "clip": args.clip, "offset_px": args.offset, "windows": len(windows), "observations": int(len(r["residual"])),
        "median_px": float(np.median(r["residual"])) if len(r["residual"]) else None,
        "by_column": medians_by(r["residual"], r["u"], list(np.linspace(0, width, 7))),
        "by_row": medians_by(r["residual"], r["v"], list(np.linspace(0, height, 6))),
        "by_level": medians_by(r["residual"], r["level"], [level - 0.5 for level in range(9)]),
        "by_disparity": medians_by(r["residual"], r["disparity"], [0, 10, 20, 35, 60, 100, 1000]),
        "machine": platform.platform(),
    }  # fmt: skip
    print(f"{args.clip}: {report['windows']} local BA windows, {report['observations']} observations, "
          f"median residual {report['median_px']:+.3f} px (predicted - measured disparity)")  # fmt: skip
    for name, unit in (("by_column", "u px"), ("by_row", "v px"), ("by_level", "level"), ("by_disparity", "disparity px")):
        label = (lambda row: f"{row['to'] - 0.5:.0f}") if name == "by_level" else (lambda row: f"{row['from']:.0f}-{row['to']:.0f}")
        cells = ", ".join(f"{label(row)}: {row['median_px']:+.3f}" for row in report[name])
        print(f"  {name[3:]:9s} ({unit}): {cells}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
