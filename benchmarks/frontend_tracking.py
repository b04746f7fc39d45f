"""Benchmark the tracking frontend end to end: per-stage timing, frames/s, lost frames and ATE.

Runs ``FrontendPipeline`` (ORB extraction, stereo matching or RGB-D depth, motion-model and
local-map tracking, pose optimisation, keyframes) over the KITTI 06 clip and the EuRoC V1_01 micro
clip, the KITTI clip monocular (its left images), and optionally the full synthetic loop (stereo and
RGB-D, 601 frames each). A monocular frontend makes no points of its own, so that run has local
mapping (``LocalMapper``, in the same process) answer each keyframe before the next frame, as
lockstep does; only the frontend's step is timed. For every stage the mean / median / max
milliseconds per frame are printed; ATE (evo; SE(3) alignment, Sim(3) for monocular) against the
ground truth. The figures are wall times on a shared machine, so the load average before and
after each run is recorded with them.

Run: ``.venv/bin/python benchmarks/frontend_tracking.py [--data ../shared/data] [--synthetic]``
(writes benchmarks/results/frontend_tracking.json).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from zenslam.frontend.pipeline import TIMING_KEYS, FrontendConfig, FrontendPipeline
from zenslam.service.evaluation.metrics import EvaluationConfig, evaluate
from zenslam.trajectory import Trajectory

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "frontend_tracking.json"


def summary(values_ms: list[float]) -> dict[str, float]:
    return {"mean": statistics.fmean(values_ms), "median": statistics.median(values_ms), "max": max(values_ms)}


def run(name: str, source) -> dict:
    """Track every frame of ``source`` once (images loaded beforehand, so reading is not timed)."""
    frames = list(source)
    pipeline = FrontendPipeline(FrontendConfig(), source.calibration, source.sensor)
    mapper = _local_mapper() if source.sensor == "mono" else None
    load_before = os.getloadavg()
    outputs = []
    wall_s = 0.0
    for frame in frames:
        start = time.perf_counter()
        outputs.append(pipeline.step(frame.index, frame.stamp_ns, frame.left, right=frame.right, depth_m=frame.depth_m))
        wall_s += time.perf_counter() - start
        if mapper is not None:
            _map_keyframes(mapper, pipeline, outputs[-1], source)
    tracked = [o for o in outputs if o.T_world_cam is not None]
    estimate = Trajectory(np.array([o.stamp_ns for o in tracked], np.int64), np.stack([o.T_world_cam for o in tracked]))
    alignment = "sim3" if source.sensor == "mono" else "se3"
    evaluation = evaluate(estimate, source.ground_truth(), EvaluationConfig(alignment=alignment))
    tracker = pipeline.tracker
    return {
        "name": name,
        "sensor": source.sensor,
        "frames": len(outputs),
        "image_size": [source.calibration.width, source.calibration.height],
        "frames_per_s": len(outputs) / wall_s,
        "states": {s: sum(o.state == s for o in outputs) for s in ("ok", "lost", "initializing")},
        "lost_reasons": dict(tracker.lost_reasons),
        "keyframes": sum(len(o.keyframes_made) for o in outputs),
        "map_points": tracker.map.n_valid_points,
        "n_tracked_median": statistics.median(o.n_tracked for o in outputs if o.state == "ok"),
        "timing_ms": {key: summary([o.timings_ms[key] for o in outputs]) for key in TIMING_KEYS},
        "ate": evaluation.to_json()["ate"],
        "path_length_m": evaluation.path_length_m,
        "load_average_1_5_15_before": load_before,
        "load_average_1_5_15_after": os.getloadavg(),
    }


def _local_mapper():
    from zenslam.backend.config import BackendConfig
    from zenslam.backend.local_mapping import LocalMapper, bundle_adjuster, new_backend_map

    config = BackendConfig()
    return LocalMapper(new_backend_map(config.local_mapping), config.local_mapping, bundle_adjuster(config.local_ba))


def _map_keyframes(mapper, pipeline, out, source) -> None:
    """Local mapping's answer to each keyframe of ``out``, applied before the next frame (lockstep's order)."""
    from zenslam.frontend.node import keyframe_message
    from zenslam.schemas import codec

    for keyframe in out.keyframes_made:
        message = codec.decode_keyframe(codec.encode_keyframe(keyframe_message(keyframe, source.calibration, source.sensor)))
        pipeline.apply_map_update(mapper.process(message))


def sources(data: Path, synthetic: bool):
    from zenslam.service.sources.euroc import EurocSource
    from zenslam.service.sources.kitti import KittiSource
    from zenslam.service.sources.sensor_selection import as_sensor

    yield "kitti_06_clip", KittiSource(data / "kitti_odometry" / "sequences" / "06")
    yield "kitti_06_clip_mono", as_sensor(KittiSource(data / "kitti_odometry" / "sequences" / "06"), "mono")
    yield "euroc_v1_01_micro", EurocSource(data / "euroc" / "V1_01_easy_micro")
    if synthetic:
        from zenslam.service.sources.synthetic import SyntheticSource, scene_config

        for sensor in ("stereo", "rgbd"):
            yield f"synthetic_loop_{sensor}", SyntheticSource(scene_config("loop", sensor=sensor))


def print_run(r: dict) -> None:
    ate = r["ate"]
    print(
        f"{r['name']} ({r['sensor']}, {r['frames']} frames): {r['frames_per_s']:.1f} frames/s, "
        f"states {r['states']}, keyframes {r['keyframes']}, median inliers {r['n_tracked_median']}, "
        f"ATE rmse {ate['rmse_m'] * 100:.2f} cm (max {ate['max_m'] * 100:.2f} cm, "
        f"{ate['rmse_percent_of_path']:.2f} % of {r['path_length_m']:.2f} m); "
        f"load {r['load_average_1_5_15_before'][0]:.1f}"
    )
    for key in TIMING_KEYS:
        t = r["timing_ms"][key]
        print(f"    {key:<22} mean {t['mean']:6.1f}  median {t['median']:6.1f}  max {t['max']:6.1f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="benchmark clips root")
    parser.add_argument("--synthetic", action="store_true", help="also run the full synthetic loop (stereo, RGB-D)")
    args = parser.parse_args()
    runs = []
    for name, source in sources(args.data, args.synthetic):
        runs.append(run(name, source))
        print_run(runs[-1])
    report = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "config": "FrontendConfig() defaults",
        "runs": runs,
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
