"""Benchmark the stereo matcher's numba kernels against the numpy formulation they replaced.

Two parts, every process in the frontend stage's environment (its math-kernel pins):
- per frame: on KITTI 06 and EuRoC V1_01 micro (features of ``OrbExtractor()``, both images), the
  process CPU time of ``match_stereo`` with the kernels and with the numpy formulation
  (tests/frontend/stereo_numpy_reference.py), alternating frame by frame in one process (the order
  swapped every frame) so that the machine's load hits both alike; and whether every output is
  the same to the bit;
- compile and cache: in fresh child processes, the first ``match_stereo`` on a KITTI frame with an
  empty NUMBA_CACHE_DIR (compiles the three kernels and writes the cache), then with the cache
  filled (loads it), each after another cached kernel has started numba (its time given apart).

Run: ``.venv/bin/python benchmarks/stereo_matching.py [--data ../shared/data] [--repeats 3]``
(writes benchmarks/results/stereo_matching.json).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "stereo_matching.json"
_FIELDS = ("right_u", "depth_m", "right_index", "sad")

_START_CHILD = """
import json, pickle, sys, time
import numpy as np
from zenslam.frontend import stereo_kernel
from zenslam.frontend.stereo_matcher import match_stereo
calibration, (left, right, left_pyramid, right_pyramid) = pickle.load(open(sys.argv[1], "rb"))
t0, c0 = time.perf_counter(), time.process_time()
stereo_kernel.popcount(np.uint64(5))  # numba's start, as after the frontend's other kernels
t1, c1 = time.perf_counter(), time.process_time()
match_stereo(left, right, left_pyramid, right_pyramid, calibration)
t2, c2 = time.perf_counter(), time.process_time()
kernels = (stereo_kernel.best_descriptor_matches, stereo_kernel.refine_level_by_sad, stereo_kernel.keep_matches)
print(json.dumps({"numba_start_wall_ms": 1e3 * (t1 - t0), "numba_start_cpu_ms": 1e3 * (c1 - c0),
                  "first_match_wall_ms": 1e3 * (t2 - t1), "first_match_cpu_ms": 1e3 * (c2 - c1),
                  "compiled": sum(sum(k.stats.cache_misses.values()) for k in kernels),
                  "loaded": sum(sum(k.stats.cache_hits.values()) for k in kernels)}))
"""


def summary(values: list[float]) -> dict[str, float]:
    return {
        "median": statistics.median(values), "mean": statistics.fmean(values), "max": max(values), "min": min(values)
    }


def clip_frames(spec: str) -> tuple:
    from zenslam.frontend.orb_extractor import OrbExtractor
    from zenslam.service.sources import open_source

    source = open_source(spec)
    extractor = OrbExtractor()
    frames = []
    for frame in source:
        (left, left_pyramid), (right, right_pyramid) = extractor.extract_pair(frame.left, frame.right)
        frames.append((left, right, left_pyramid, right_pyramid))
    return source.calibration, frames


def per_frame(calibration, frames: list, repeats: int) -> dict:
    sys.path.insert(0, str(REPO / "tests" / "frontend"))
    from stereo_numpy_reference import match_stereo as numpy_match_stereo

    from zenslam.frontend.stereo_matcher import match_stereo

    variants = {"numba": match_stereo, "numpy": numpy_match_stereo}
    match_stereo(*frames[0], calibration)  # loads the kernels (timed in start_cost)
    spent: dict[str, list[float]] = {name: [] for name in variants}
    identical = True
    for repeat in range(repeats):
        for index, frame in enumerate(frames):
            order = list(variants) if (index + repeat) % 2 == 0 else list(reversed(variants))
            out = {}
            for name in order:
                c0 = time.process_time()
                out[name] = variants[name](*frame, calibration)
                spent[name].append(1e3 * (time.process_time() - c0))
            identical &= all(getattr(out["numba"], f).tobytes() == getattr(out["numpy"], f).tobytes() for f in _FIELDS)
    return {
        "frames": len(frames),
        "repeats": repeats,
        "cpu_ms": {name: summary(values) for name, values in spent.items()},
        "median_ratio_numpy_over_numba": statistics.median(spent["numpy"]) / statistics.median(spent["numba"]),
        "identical": identical,
    }


def start_cost(calibration, frame: tuple) -> dict:
    from zenslam.runtime.supervisor import stage_environment

    with tempfile.TemporaryDirectory() as folder:
        inputs = Path(folder) / "frame.pkl"
        inputs.write_bytes(pickle.dumps((calibration, frame)))
        cache = Path(folder) / "numba_cache"
        stage_env = stage_environment(os.environ, "zenslam.frontend.node")
        env = {k: v for k, v in stage_env.items() if not k.startswith("NUMBA_")}
        env["NUMBA_CACHE_DIR"] = str(cache)

        def child() -> dict:
            command = [sys.executable, "-c", _START_CHILD, str(inputs)]
            result = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
            return json.loads(result.stdout.splitlines()[-1])

        return {"empty_cache": child(), "filled_cache": [child() for _ in range(2)]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="benchmark clips root")
    parser.add_argument("--repeats", type=int, default=3, help="passes over each clip's frames")
    args = parser.parse_args()
    from zenslam.runtime.supervisor import stage_environment

    env = stage_environment(os.environ, "zenslam.frontend.node")
    if any(os.environ.get(name) != value for name, value in env.items()):
        # the pins are read when numpy and OpenCV load: start again in the frontend's environment
        os.execve(sys.executable, [sys.executable, *sys.argv], env)
    load_before = os.getloadavg()
    clips = {
        "kitti_06": f"kitti:{args.data / 'kitti_odometry' / 'sequences' / '06'}",
        "euroc_v1_01_micro": f"euroc:{args.data / 'euroc' / 'V1_01_easy_micro'}",
    }
    report: dict = {"machine": platform.platform(), "python": platform.python_version(), "cpu_count": os.cpu_count()}
    for name, spec in clips.items():
        calibration, frames = clip_frames(spec)
        report[name] = per_frame(calibration, frames, args.repeats)
        if name == "kitti_06":
            report["start"] = start_cost(calibration, frames[0])
        cpu = report[name]["cpu_ms"]
        print(
            f"{name}: {len(frames)} frames x {args.repeats}, match_stereo CPU per frame: "
            f"numpy median {cpu['numpy']['median']:.2f} ms (mean {cpu['numpy']['mean']:.2f}), "
            f"numba median {cpu['numba']['median']:.2f} ms (mean {cpu['numba']['mean']:.2f}), "
            f"ratio {report[name]['median_ratio_numpy_over_numba']:.1f}; identical: {report[name]['identical']}"
        )
    start = report["start"]
    print(
        f"first match_stereo: empty cache {start['empty_cache']['first_match_cpu_ms']:.0f} ms CPU "
        f"({start['empty_cache']['compiled']} kernels compiled), filled cache "
        + ", ".join(f"{r['first_match_cpu_ms']:.0f}" for r in start["filled_cache"])
        + f" ms CPU ({start['filled_cache'][0]['loaded']} loaded); numba start before it "
        + ", ".join(f"{r['numba_start_cpu_ms']:.0f}" for r in start["filled_cache"])
        + " ms CPU"
    )
    report["load_average_1_5_15_before"] = load_before
    report["load_average_1_5_15_after"] = os.getloadavg()
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"load average before {load_before}, after {report['load_average_1_5_15_after']}; wrote {RESULTS}")


if __name__ == "__main__":
    main()
