"""Benchmark whole runs (source, frontend and backend processes over zenoh) against real time, live and lockstep.

For the KITTI 06 clip (51 frames, 10 Hz) and the EuRoC V1_01 micro clip (95 frames, 20 Hz), runs
``zenslam run <clip> --lockstep`` and ``--live`` as a user would and records:
- the command's wall time (process start-up included) and the streaming span, from the frontend's
  first frame to the backend's end of stream (from the stage logs' timestamps), against the
  clip's real duration;
- frames tracked and skipped, keyframes sent by the frontend and processed by the backend;
- the backend's time per keyframe for each local-mapping step (insertion, point culling,
  triangulation, fusion, local BA, keyframe culling, total: mean / median / max ms), the most
  keyframes waiting in its inbox, and the frontend's total per frame;
- ATE of the per-frame trajectory (and of keyframes.tum, the backend's final keyframe poses).
Wall times on a shared 2-core machine: the load average before each run is recorded with it.

Run: ``/work/venv/bin/python benchmarks/pipeline.py [--data ../shared/data] [--modes lockstep live]``
(writes benchmarks/results/pipeline.json).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

import numpy as np

from zenslam.errors import TrajectoryError
from zenslam.service.evaluation.metrics import evaluate
from zenslam.service.evaluation.trajectory_io import read_tum
from zenslam.service.sources import open_source

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "pipeline.json"
_STAMP = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) ")


def real_time_s(spec: str) -> float:
    """The clip's duration as recorded: last minus first stamp plus one frame period, seconds."""
    stamps = np.asarray(open_source(spec).stamps_ns(), dtype=np.int64)
    return float((stamps[-1] - stamps[0] + np.median(np.diff(stamps))) * 1e-9)


def stream_span_s(run_dir: Path) -> float | None:
    """Seconds from the frontend's first frame to the backend's end of stream, from the run's stage logs."""
    first = log_time(run_dir / "logs" / "frontend.log", "first frame")
    end = log_time(run_dir / "logs" / "backend.log", "end of stream")
    return None if first is None or end is None else end - first


def log_time(path: Path, pattern: str) -> float | None:
    """POSIX time of the first line of a stage log containing ``pattern``."""
    for line in path.read_text(errors="replace").splitlines():
        match = _STAMP.match(line)
        if match and pattern in line:
            return datetime.strptime(match.group(1), "%Y-%m-%d %H:%M:%S,%f").timestamp()
    return None


def run(name: str, spec: str, mode: str, output: Path) -> dict:
    """One ``zenslam run`` of ``spec`` in ``mode`` (lockstep or live); its figures."""
    run_id = f"{name}-{mode}"
    command = [sys.executable, "-m", "zenslam.service.cli", "run", spec, f"--{mode}", "--output", str(output),
               "--run-id", run_id, "--no-progress"]  # fmt: skip
    load = os.getloadavg()
    start = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True, timeout=1800)
    wall_s = time.perf_counter() - start
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{result.stdout[-2000:]}\n{result.stderr[-3000:]}")
    run_dir = output / run_id
    metrics = json.loads((run_dir / "metrics.json").read_text())
    span_s = stream_span_s(run_dir)
    truth = open_source(spec).ground_truth()
    try:
        keyframes_ate = evaluate(read_tum(run_dir / "keyframes.tum"), truth).ate.rmse_m
    except TrajectoryError:  # e.g. one keyframe on a still clip: nothing to align
        keyframes_ate = None
    real_s = real_time_s(spec)
    return {
        "name": name,
        "mode": mode,
        "real_time_s": real_s,
        "command_wall_s": wall_s,
        "stream_span_s": span_s,
        "stream_span_over_real_time": span_s / real_s if span_s is not None else None,
        "frames_in_clip": len(open_source(spec)),
        "frames_tracked": metrics["frames"],
        "frames_ok": metrics["tracked_ok"],
        "keyframes": metrics["keyframes"],
        "backend_queue_depth_max": metrics["backend_queue_depth_max"],
        "backend_timing_ms": metrics["backend_timing"],
        "frontend_total_ms": metrics["timing"].get("total"),
        "ate_rmse_m": metrics.get("ate", {}).get("rmse_m"),
        "keyframes_ate_rmse_m": keyframes_ate,
        "load_average_1_5_15_before": load,
    }


def _m(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.4f} m"


def print_run(r: dict) -> None:
    span = f"{r['stream_span_s']:.2f} s ({r['stream_span_over_real_time']:.2f}x real time)" if r["stream_span_s"] else "n/a"
    print(
        f"{r['name']} {r['mode']}: real time {r['real_time_s']:.2f} s, command {r['command_wall_s']:.2f} s, stream {span}; "
        f"frames {r['frames_tracked']}/{r['frames_in_clip']} ({r['frames_ok']} ok), keyframes sent {r['keyframes']['sent']} "
        f"processed {r['keyframes']['processed']} (at most {r['backend_queue_depth_max']} queued); ATE {r['ate_rmse_m']:.4f} m (keyframes {_m(r['keyframes_ate_rmse_m'])}); "
        f"load {r['load_average_1_5_15_before'][0]:.1f}"
    )
    for step, t in r["backend_timing_ms"].items():
        print(f"    backend {step:<17} mean {t['mean_ms']:7.1f}  median {t['median_ms']:7.1f}  max {t['max_ms']:7.1f} ms")
    t = r["frontend_total_ms"]
    if t:
        print(f"    frontend total            mean {t['mean_ms']:7.1f}  median {t['median_ms']:7.1f}  max {t['max_ms']:7.1f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="benchmark clips root")
    parser.add_argument("--modes", nargs="+", choices=("lockstep", "live"), default=["lockstep", "live"])
    args = parser.parse_args()
    clips = {
        "kitti_06_clip": f"kitti:{args.data / 'kitti_odometry' / 'sequences' / '06'}",
        "euroc_v1_01_micro": f"euroc:{args.data / 'euroc' / 'V1_01_easy_micro'}",
    }
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, spec in clips.items():
            for mode in args.modes:
                runs.append(run(name, spec, mode, Path(tmp)))
                print_run(runs[-1])
    report = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "config": "RunConfig() defaults; live runs at the recorded rate (source.rate 1)",
        "runs": runs,
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
