"""Benchmark what recording to MCAP costs a run: a lockstep KITTI 06 clip with and without the recorder.

Runs ``zenslam run kitti:<data>/kitti_odometry/sequences/06 --lockstep`` alternately with
``recorder.enabled`` false and true (``--repeats`` times each) and records, per run:
- the streaming span, from the frontend's first frame to the backend's end of stream (from the
  stage logs' timestamps): the time tracking and mapping took, start-up excluded;
- the command's wall time, start-up included;
- with the recorder: run.mcap's size and message count.
The ratio of the median spans (with / without) is printed; the issue's target is <= 1.10.
Wall times on a shared 2-core machine: the load average before each run is recorded with it.

Run: ``.venv/bin/python benchmarks/recording_overhead.py [--data ../shared/data] [--repeats 2]
[--image-format png|jpeg]`` (writes benchmarks/results/recording_overhead.json).
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
from datetime import datetime
from pathlib import Path

from mcap.reader import make_reader
from pipeline import stream_span_s  # same measurement as the pipeline benchmark (benchmarks/ is on sys.path)

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "recording_overhead.json"



def one_run(spec: str, recorder: bool, image_format: str, output: Path, run_id: str) -> dict:
    """One lockstep ``zenslam run``; its span, wall time and (with the recorder) recording size."""
    config = output / f"{run_id}.yaml"
    config.write_text(f"recorder:\n  enabled: {str(recorder).lower()}\n  image_format: {image_format}\n")
    command = [sys.executable, "-m", "zenslam.service.cli", "run", spec, "--lockstep", "--config", str(config),
               "--output", str(output), "--run-id", run_id, "--no-progress"]  # fmt: skip
    load = os.getloadavg()[0]
    start = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True, timeout=1800)
    wall_s = time.perf_counter() - start
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{result.stdout[-2000:]}\n{result.stderr[-3000:]}")
    run_dir = output / run_id
    figures = {"recorder": recorder, "span_s": stream_span_s(run_dir),
               "wall_s": wall_s, "load_1min_before": load}  # fmt: skip
    mcap_path = run_dir / "run.mcap"
    if recorder:
        with open(mcap_path, "rb") as f:
            summary = make_reader(f).get_summary()
        figures["mcap_mb"] = mcap_path.stat().st_size / 1e6
        figures["mcap_messages"] = summary.statistics.message_count
    return figures


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="the shared benchmark clips")
    parser.add_argument("--repeats", type=int, default=2, help="runs with and without the recorder each")
    parser.add_argument("--image-format", choices=("png", "jpeg"), default="png", help="the recorder's /camera/* encoding")
    args = parser.parse_args()
    sequence = args.data / "kitti_odometry" / "sequences" / "06"
    if not sequence.is_dir():
        raise SystemExit(f"KITTI clip not found at {sequence}; pass --data")
    spec = f"kitti:{sequence}"
    runs = []
    with tempfile.TemporaryDirectory(prefix="zenslam-recbench-") as tmp:
        for i in range(args.repeats):
            for recorder in (False, True):  # alternate, so a load change hits both alike
                figures = one_run(spec, recorder, args.image_format, Path(tmp), f"r{i}-{'rec' if recorder else 'norec'}")
                print(json.dumps(figures))
                runs.append(figures)
    spans = {flag: [r["span_s"] for r in runs if r["recorder"] == flag and r["span_s"] is not None] for flag in (False, True)}
    walls = {flag: [r["wall_s"] for r in runs if r["recorder"] == flag] for flag in (False, True)}
    span_ratio = statistics.median(spans[True]) / statistics.median(spans[False])
    wall_ratio = statistics.median(walls[True]) / statistics.median(walls[False])
    result = {
        "clip": "KITTI 06 frames 0-50, lockstep",
        "image_format": args.image_format,
        "median_span_s": {"without": statistics.median(spans[False]), "with": statistics.median(spans[True])},
        "median_wall_s": {"without": statistics.median(walls[False]), "with": statistics.median(walls[True])},
        "span_ratio": span_ratio,
        "wall_ratio": wall_ratio,
        "target_ratio": 1.10,
        "runs": runs,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "date": datetime.now().isoformat(timespec="seconds"),
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2))
    print(f"streaming span with/without recorder: {span_ratio:.3f} (wall {wall_ratio:.3f}); target <= 1.10 -> {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
