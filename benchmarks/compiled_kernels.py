"""Benchmark the ORB extractor's numba kernels: what numba costs a process, and what the kernels save.

Three parts, each in fresh child processes where start-up is measured:
- import: wall and CPU time of ``import numba`` and the RSS it adds, in a process that has already
  imported numpy, OpenCV and the extractor's other dependencies;
- compile and cache: the first ``OrbExtractor.extract`` with an empty NUMBA_CACHE_DIR (compiles and
  writes the cache), then with the cache filled (loads it), for the machine's CPU and for
  NUMBA_CPU_NAME=generic;
- kernels: per KITTI 06 frame (both images, threads=1), the calling thread's CPU time of
  ``distribute_quadtree``, of the intensity-centroid angles and of the whole ``extract``, with the
  kernels and with the numpy formulation they replaced (tests/frontend/orb_numpy_reference.py),
  alternating frame by frame in one process so that the machine's load hits both alike;
- descriptors: per KITTI 06 image (20 images, threads=1), the process CPU time of the rBRIEF
  descriptors (``describe``: blur and kernel) and of the whole ``extract``, with the kernel and with
  the OpenCV ORB.compute it replaced (tests/frontend/orb_opencv_reference.py), alternating image
  by image in one process.
Every process runs with the stage processes' pinned math kernels, like a stage.

Run: ``.venv/bin/python benchmarks/compiled_kernels.py [--data ../shared/data] [--repeats 3]``
(writes benchmarks/results/compiled_kernels.json).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "compiled_kernels.json"

_IMPORT_CHILD = """
import json, time
def rss_mb():
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmRSS"))
import cv2, numpy, scipy  # what a stage has loaded before the extractor
import zenslam.errors
before, t0, c0 = rss_mb(), time.perf_counter(), time.process_time()
import numba
print(json.dumps({"wall_ms": 1e3 * (time.perf_counter() - t0), "cpu_ms": 1e3 * (time.process_time() - c0),
                  "rss_before_mb": before, "rss_added_mb": rss_mb() - before}))
"""

_START_CHILD = """
import json, time
import numpy as np
import cv2
from zenslam.frontend.orb_extractor import OrbExtractor
image = cv2.GaussianBlur(np.random.default_rng(5).integers(0, 256, (370, 1226), dtype=np.uint8), (0, 0), 1.5)
t0, c0 = time.perf_counter(), time.process_time()
OrbExtractor().extract(image)
t1, c1 = time.perf_counter(), time.process_time()
OrbExtractor().extract(image)
t2 = time.perf_counter()
print(json.dumps({"first_extract_wall_ms": 1e3 * (t1 - t0), "first_extract_cpu_ms": 1e3 * (c1 - c0),
                  "second_extract_wall_ms": 1e3 * (t2 - t1)}))
"""


def child(code: str, **env: str) -> dict:
    from zenslam.runtime.cpu_kernels import with_pinned_kernels

    environment = with_pinned_kernels({k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")} | env)
    result = subprocess.run([sys.executable, "-c", code], env=environment, capture_output=True, text=True, check=True)
    return json.loads(result.stdout.splitlines()[-1])


def summary(values: list[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "mean": statistics.fmean(values), "min": min(values)}


def import_cost(repeats: int) -> dict:
    runs = [child(_IMPORT_CHILD) for _ in range(repeats)]
    return {key: summary([r[key] for r in runs]) for key in runs[0]}


def start_cost(cpu_name: str | None, code: str = _START_CHILD) -> dict:
    """``code``'s figures in a fresh process with an empty numba cache (compile), then twice with it filled (load)."""
    env = {} if cpu_name is None else {"NUMBA_CPU_NAME": cpu_name}
    with tempfile.TemporaryDirectory() as cache:
        compiling = child(code, NUMBA_CACHE_DIR=cache, **env)
        loading = [child(code, NUMBA_CACHE_DIR=cache, **env) for _ in range(2)]
    return {"cpu": cpu_name or "host", "empty_cache": compiling, "filled_cache": loading}


def kernel_times(data: Path, repeats: int) -> dict:
    sys.path.insert(0, str(REPO / "tests" / "frontend"))
    from orb_numpy_reference import reference_angles, reference_quadtree

    from zenslam.frontend import orb_extractor
    from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
    from zenslam.service.sources.kitti import KittiSource

    compiled = {"distribute_quadtree": orb_extractor.distribute_quadtree, "intensity_centroid_angles": orb_extractor.intensity_centroid_angles}
    numpy_version = {"distribute_quadtree": reference_quadtree, "intensity_centroid_angles": lambda image, xy, u_max: reference_angles(image, xy)}
    spent: dict[str, float] = {}

    def timed(name, function):
        def wrapper(*args):
            c0 = time.thread_time()
            out = function(*args)
            spent[name] = spent.get(name, 0.0) + time.thread_time() - c0
            return out
        return wrapper

    images = [image for frame in KittiSource(data / "kitti_odometry" / "sequences" / "06") for image in (frame.left, frame.right)]
    extractor = OrbExtractor(OrbConfig(threads=1))
    extractor.extract(images[0])  # loads the kernels from the cache (or compiles them): timed in start_cost
    figures = {variant: {"distribute_quadtree": [], "intensity_centroid_angles": [], "extract": []} for variant in ("numba", "numpy")}
    for _ in range(repeats):
        for pair in range(0, len(images), 2):
            for variant, functions in (("numba", compiled), ("numpy", numpy_version)):
                for name, function in functions.items():
                    setattr(orb_extractor, name, timed(name, function))
                spent.clear()
                c0 = time.thread_time()
                for image in images[pair : pair + 2]:
                    extractor.extract(image)
                figures[variant]["extract"].append(1e3 * (time.thread_time() - c0))
                for name in functions:
                    figures[variant][name].append(1e3 * spent[name])
    for name, function in compiled.items():
        setattr(orb_extractor, name, function)
    return {variant: {name: summary(values) for name, values in parts.items()} for variant, parts in figures.items()}


def descriptor_times(data: Path, repeats: int, n_images: int = 20) -> dict:
    sys.path.insert(0, str(REPO / "tests" / "frontend"))
    from orb_opencv_reference import reference_describe, reference_orb

    from zenslam.frontend import orb_extractor
    from zenslam.frontend.orb_extractor import OrbConfig, OrbExtractor
    from zenslam.service.sources.kitti import KittiSource

    orb = reference_orb()
    variants = {"kernel": orb_extractor.describe, "orb_compute": lambda image, xy, angle, pattern: reference_describe(image, xy, angle, orb)}
    spent = [0.0]

    def timed(function):
        def wrapper(*args):
            c0 = time.process_time()
            out = function(*args)
            spent[0] += time.process_time() - c0
            return out
        return wrapper

    images = [image for frame in KittiSource(data / "kitti_odometry" / "sequences" / "06") for image in (frame.left, frame.right)][:n_images]
    extractor = OrbExtractor(OrbConfig(threads=1))
    extractor.extract(images[0])
    figures = {variant: {"describe": [], "extract": []} for variant in variants}
    for _ in range(repeats):
        for image in images:
            for variant, function in variants.items():
                orb_extractor.describe = timed(function)
                spent[0] = 0.0
                c0 = time.process_time()
                extractor.extract(image)
                figures[variant]["extract"].append(1e3 * (time.process_time() - c0))
                figures[variant]["describe"].append(1e3 * spent[0])
    orb_extractor.describe = variants["kernel"]
    return {variant: {name: summary(values) for name, values in parts.items()} for variant, parts in figures.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="benchmark clips root")
    parser.add_argument("--repeats", type=int, default=3, help="child processes per import figure; passes over the clip")
    parser.add_argument("--descriptors-only", action="store_true", help="only the descriptor figures (printed, not written)")
    args = parser.parse_args()
    from zenslam.runtime.cpu_kernels import kernel_pins, with_pinned_kernels

    if not all(os.environ.get(name) == value for name, value in kernel_pins(os.environ).items()):
        # the pins are read when numpy and OpenCV load: start again with them set, like a stage
        os.execve(sys.executable, [sys.executable, *sys.argv], with_pinned_kernels(os.environ))
    import numba

    if args.descriptors_only:
        for variant, parts in descriptor_times(args.data, args.repeats).items():
            print(variant + ": " + ", ".join(f"{name} {s['median']:.2f} ms (mean {s['mean']:.2f})" for name, s in parts.items()) + " per image")
        return
    load_before = os.getloadavg()
    report = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "numba": numba.__version__,
        "load_average_1_5_15_before": load_before,
        "import": import_cost(args.repeats),
        "start": [start_cost(None), start_cost("generic")],
        "per_frame_cpu_ms": kernel_times(args.data, args.repeats),
        "per_image_descriptor_cpu_ms": descriptor_times(args.data, args.repeats),
        "load_average_1_5_15_after": os.getloadavg(),
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    i = report["import"]
    print(f"import numba: {i['wall_ms']['median']:.0f} ms wall, {i['cpu_ms']['median']:.0f} ms CPU, "
          f"+{i['rss_added_mb']['median']:.1f} MB RSS (on {i['rss_before_mb']['median']:.0f} MB)")
    for start in report["start"]:
        filled = statistics.median(r["first_extract_cpu_ms"] for r in start["filled_cache"])
        print(f"{start['cpu']}: first extract {start['empty_cache']['first_extract_cpu_ms']:.0f} ms CPU with an empty cache, "
              f"{filled:.0f} ms from the cache; second extract {start['empty_cache']['second_extract_wall_ms']:.0f} ms wall")
    for variant, parts in report["per_frame_cpu_ms"].items():
        print(variant + ": " + ", ".join(f"{name} {s['median']:.2f} ms (mean {s['mean']:.2f})" for name, s in parts.items()) + " per frame (2 images)")
    for variant, parts in report["per_image_descriptor_cpu_ms"].items():
        print(variant + ": " + ", ".join(f"{name} {s['median']:.2f} ms (mean {s['mean']:.2f})" for name, s in parts.items()) + " per image")
    print(f"load average before {load_before}, after {report['load_average_1_5_15_after']}; wrote {RESULTS}")


if __name__ == "__main__":
    main()
