"""Benchmark the ORB extractor's FAST: the compiled kernel (frontend/orb_fast.py) against the OpenCV path it replaced.

- per image: process CPU time of ``OrbExtractor.extract`` on every KITTI 06 image (left and right,
  threads=1), with the kernel and with the former OpenCV FastFeatureDetector + mosaic path
  (tests/frontend/orb_fast_reference.py's ``mosaic_detect_cells``), alternating the two image by
  image in one process so that both see the same machine load; and of the per-cell detection alone
  (``_detect_cells`` over the 8 levels of the image), the two alternated likewise.
- start: the kernel's first call in fresh processes, with an empty numba cache (compile) and then
  with the filled one (load), on the host CPU and on numba's generic x86-64 target.

Every process runs in the frontend stage's environment (pinned math kernels, thread pools of one),
like the stage.

Run: ``.venv/bin/python benchmarks/frontend_fast.py [--data ../shared/data] [--repeats 3]``
(writes benchmarks/results/frontend_fast.json).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

from compiled_kernels import start_cost, summary

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "frontend_fast.json"
_MARK = "ZENSLAM_BENCHMARK_STAGE_ENV"  # set once the process runs in the stage's environment

_START_CHILD = """
import json, time
t0 = time.perf_counter()
import numpy as np
from zenslam.frontend.orb_fast import fast_in_windows
t1, c1 = time.perf_counter(), time.process_time()
image = np.random.default_rng(0).integers(0, 256, (64, 64), dtype=np.uint8)
fast_in_windows(image, np.array([[0, 0, 64, 64]]), 20)
t2 = time.perf_counter()
print(json.dumps({"import_ms": 1e3 * (t1 - t0), "first_call_ms": 1e3 * (t2 - t1), "first_call_cpu_ms": 1e3 * (time.process_time() - c1)}))
"""


def per_image(data: Path, repeats: int) -> dict:
    import numpy as np

    from zenslam.frontend import orb_extractor
    from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
    from zenslam.service.sources.kitti import KittiSource

    sys.path.insert(0, str(REPO / "tests" / "frontend"))
    from orb_fast_reference import mosaic_detect_cells

    images = [image for frame in KittiSource(data / "kitti_odometry" / "sequences" / "06") for image in (frame.left, frame.right)]
    extractor = OrbExtractor(OrbConfig(threads=1))
    variants = {"kernel": orb_extractor._detect_cells, "opencv_mosaic": mosaic_detect_cells}
    extract = {name: [] for name in variants}
    detect = {name: [] for name in variants}
    for name, function in variants.items():  # warm-up: kernels loaded, OpenCV's allocations made
        orb_extractor._detect_cells = function
        extractor.extract(images[0])
    for _ in range(repeats):
        for image in images:
            pyramid = extractor.build_pyramid(image)
            for name, function in variants.items():
                orb_extractor._detect_cells = function
                c0 = time.process_time()
                extractor.extract(image)
                c1 = time.process_time()
                for level in pyramid:
                    function(level, extractor.config)
                c2 = time.process_time()
                extract[name].append(1e3 * (c1 - c0))
                detect[name].append(1e3 * (c2 - c1))
    orb_extractor._detect_cells = variants["kernel"]
    result = {
        "images": len(images),
        "repeats": repeats,
        "extract_cpu_ms": {name: summary(v) for name, v in extract.items()},
        "detect_cells_8_levels_cpu_ms": {name: summary(v) for name, v in detect.items()},
    }
    result["extract_median_ratio_kernel_over_opencv"] = float(
        np.median(np.array(extract["kernel"]) / np.array(extract["opencv_mosaic"]))
    )
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="benchmark clips root")
    parser.add_argument("--repeats", type=int, default=3, help="passes over the clip's 102 images")
    args = parser.parse_args()
    if os.environ.get(_MARK) != "1":
        # the stage's settings are read when numpy and OpenCV load: start again with them set
        from zenslam.runtime.supervisor import stage_environment

        environment = stage_environment(os.environ, "zenslam.frontend.node") | {_MARK: "1"}
        os.execve(sys.executable, [sys.executable, *sys.argv], environment)
    load_before = os.getloadavg()
    report = {
        "machine": platform.platform(),
        "cpu_count": os.cpu_count(),
        "load_average_1_5_15_before": load_before,
        "start": [start_cost(None, _START_CHILD), start_cost("generic", _START_CHILD)],
        "per_image": per_image(args.data, args.repeats),
        "load_average_1_5_15_after": os.getloadavg(),
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    images = report["per_image"]
    for name in ("kernel", "opencv_mosaic"):
        e, d = images["extract_cpu_ms"][name], images["detect_cells_8_levels_cpu_ms"][name]
        print(f"{name:14s} extract median {e['median']:.2f} ms (mean {e['mean']:.2f}), per-cell FAST of 8 levels median {d['median']:.2f} ms (mean {d['mean']:.2f})")
    print(f"extract, kernel / OpenCV per image: median {images['extract_median_ratio_kernel_over_opencv']:.3f}")
    for start in report["start"]:
        loads = ", ".join(f"{s['first_call_ms']:.0f} ({s['first_call_cpu_ms']:.0f})" for s in start["filled_cache"])
        compiling = start["empty_cache"]
        print(
            f"start ({start['cpu']}): first call {compiling['first_call_ms']:.0f} ms (CPU {compiling['first_call_cpu_ms']:.0f}) "
            f"with an empty cache, {loads} ms from the cache"
        )
    print(f"load average before {load_before}, after {report['load_average_1_5_15_after']}; wrote {RESULTS}")


if __name__ == "__main__":
    main()
