"""Benchmark: synthetic scene rendering speed (stereo and RGB-D frames per second at 640x480).

Usage: python benchmarks/synthetic_render.py [--scene loop] [--frames 100] [--warmup 5]
Prints frames/s and ms per frame (mean, median, max) and writes benchmarks/results/synthetic_render.json
(synthetic_render_<scene>.json for a scene other than loop).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

from zenslam.service.sources.synthetic import SCENE_NAMES, SyntheticSource, scene_config

RESULTS = Path(__file__).resolve().parent / "results" / "synthetic_render.json"


def time_frames(source: SyntheticSource, frames: int, warmup: int) -> list[float]:
    """Milliseconds to produce each of ``frames`` frames spread over the sequence, after ``warmup`` frames."""
    for index in range(warmup):
        source.frame(index)
    step = max(1, len(source) // frames)
    timings = []
    for index in range(0, step * frames, step):
        start = time.perf_counter()
        source.frame(index % len(source))
        timings.append((time.perf_counter() - start) * 1e3)
    return timings


def summary(timings_ms: list[float]) -> dict[str, float]:
    mean = statistics.fmean(timings_ms)
    return {
        "frames": len(timings_ms),
        "frames_per_s": 1e3 / mean,
        "ms_mean": mean,
        "ms_median": statistics.median(timings_ms),
        "ms_max": max(timings_ms),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100, help="frames timed per sensor")
    parser.add_argument("--warmup", type=int, default=5, help="frames rendered before timing")
    parser.add_argument("--scene", default="loop", choices=SCENE_NAMES, help="synthetic scene to render")
    args = parser.parse_args()

    stereo = SyntheticSource(scene_config(args.scene, sensor="stereo"))
    start = time.perf_counter()
    scene = stereo.scene
    build_s = time.perf_counter() - start
    rgbd = SyntheticSource(scene_config(args.scene, sensor="rgbd"), scene=scene)
    results = {
        "scene": args.scene,
        "image": "640x480",
        "scene_build_s": build_s,
        "tiles": len(scene.tiles),
        "stereo": summary(time_frames(stereo, args.frames, args.warmup)),
        "rgbd": summary(time_frames(rgbd, args.frames, args.warmup)),
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "load_avg_1min": os.getloadavg()[0]},
    }
    print(f"scene build: {build_s:.2f} s ({len(scene.tiles)} tiles)")
    for sensor in ("stereo", "rgbd"):
        r = results[sensor]
        print(
            f"{sensor:>6}: {r['frames_per_s']:6.1f} frames/s   ms/frame mean {r['ms_mean']:.1f}  "
            f"median {r['ms_median']:.1f}  max {r['ms_max']:.1f}  ({r['frames']} frames)"
        )
    path = RESULTS if args.scene == "loop" else RESULTS.with_name(f"synthetic_render_{args.scene}.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
