"""Benchmark ORB extraction of a stereo pair and stereo matching on the KITTI 06 clip (1226x370).

Per frame: wall time of ``OrbExtractor.extract_pair`` (left and right, with the right image in a
worker thread when ``threads=2``), of ``match_stereo``, and their sum; also the number of stereo
points with depth in [0.5, 200] m. Variants: 1200 features (the default) and 2000 (ORB-SLAM2's
KITTI setting), each with 1 and 2 extraction threads. The machine's load average is recorded
because the figures are wall times on a shared 2-core machine; the calling thread's CPU time is
recorded too (with threads=1 it is the whole work, and does not depend on the load).

Run: ``.venv/bin/python benchmarks/frontend_extraction.py [--data ../shared/data] [--repeats 2]
[--cv-threads 1] [--kernels pinned|machine]`` (writes benchmarks/results/frontend_extraction[_cv_threads_N].json). ``--cv-threads 1`` turns off
OpenCV's internal thread pool, which only adds synchronisation when the pair is already split
over two threads.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
from zenslam.frontend.stereo_matcher import match_stereo
from zenslam.runtime.cpu_kernels import kernel_pins, with_pinned_kernels
from zenslam.service.sources.kitti import KittiSource

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "frontend_extraction.json"


def summary(values_ms: list[float]) -> dict[str, float]:
    return {
        "mean": statistics.fmean(values_ms),
        "median": statistics.median(values_ms),
        "max": max(values_ms),
        "min": min(values_ms),
    }


def run_variant(
    pairs: list[tuple[np.ndarray, np.ndarray]], source: KittiSource, n_features: int, threads: int, repeats: int
) -> dict:
    extractor = OrbExtractor(OrbConfig(n_features=n_features, threads=threads))
    extractor.extract_pair(*pairs[0])  # warm-up: thread start, OpenCV allocations
    extraction, stereo, total, cpu, points = [], [], [], [], []
    for _ in range(repeats):
        for left, right in pairs:
            c0, t0 = time.thread_time(), time.perf_counter()
            (f_left, p_left), (f_right, p_right) = extractor.extract_pair(left, right)
            t1 = time.perf_counter()
            matches = match_stereo(f_left, f_right, p_left, p_right, source.calibration)
            t2, c2 = time.perf_counter(), time.thread_time()
            extraction.append((t1 - t0) * 1e3)
            stereo.append((t2 - t1) * 1e3)
            total.append((t2 - t0) * 1e3)
            cpu.append((c2 - c0) * 1e3)
            points.append(int(((matches.depth_m >= 0.5) & (matches.depth_m <= 200.0)).sum()))
    return {
        "n_features": n_features,
        "threads": threads,
        "frames": len(extraction),
        "extract_pair_ms": summary(extraction),
        "stereo_matching_ms": summary(stereo),
        "extract_pair_plus_stereo_ms": summary(total),
        # CPU time of the calling thread (with threads=1: the whole pair + stereo, independent of load)
        "calling_thread_cpu_ms": summary(cpu),
        "stereo_points_median": statistics.median(points),
        "stereo_points_min": min(points),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="benchmark clips root")
    parser.add_argument("--repeats", type=int, default=2, help="passes over the 51 frames per variant")
    parser.add_argument(
        "--cv-threads", type=int, default=-1, help="cv2.setNumThreads value (-1: leave OpenCV's default)"
    )
    parser.add_argument(
        "--kernels", choices=("pinned", "machine"), default="pinned",
        help="pinned: the math kernels the stage processes use (default); machine: the CPU's own choice",
    )
    args = parser.parse_args()
    pinned = all(os.environ.get(name) == value for name, value in kernel_pins(os.environ).items())
    if args.kernels == "pinned" and not pinned:
        # the pins are read when numpy and OpenCV load: start again with them set
        os.execve(sys.executable, [sys.executable, *sys.argv], with_pinned_kernels(os.environ))
    if args.cv_threads >= 0:
        cv2.setNumThreads(args.cv_threads)
    source = KittiSource(args.data / "kitti_odometry" / "sequences" / "06")
    pairs = [(frame.left, frame.right) for frame in source]
    load_before = os.getloadavg()
    results = [
        run_variant(pairs, source, n_features, threads, args.repeats)
        for n_features in (1200, 2000)
        for threads in (2, 1)
    ]
    report = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "opencv": cv2.__version__,
        "opencv_threads": cv2.getNumThreads(),
        "kernels": "pinned" if pinned else "machine",
        "cpu_count": os.cpu_count(),
        "load_average_1_5_15_before": load_before,
        "load_average_1_5_15_after": os.getloadavg(),
        "clip": "KITTI 06 frames 0-50, 1226x370",
        "results": results,
    }
    stem = RESULTS.stem + ("" if args.cv_threads < 0 else f"_cv_threads_{args.cv_threads}") + ("" if pinned else "_machine_kernels")
    output = RESULTS.with_name(stem + ".json")
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(json.dumps(report, indent=2) + "\n")
    for r in results:
        print(
            f"n_features={r['n_features']} threads={r['threads']}: "
            f"extract_pair median {r['extract_pair_ms']['median']:.1f} ms (mean {r['extract_pair_ms']['mean']:.1f}), "
            f"stereo median {r['stereo_matching_ms']['median']:.1f} ms (mean {r['stereo_matching_ms']['mean']:.1f}), "
            f"sum median {r['extract_pair_plus_stereo_ms']['median']:.1f} ms "
            f"(calling-thread CPU {r['calling_thread_cpu_ms']['median']:.1f} ms), "
            f"stereo points median {r['stereo_points_median']}"
        )
    print(f"load average before {load_before}, after {report['load_average_1_5_15_after']}; wrote {output}")


if __name__ == "__main__":
    main()
