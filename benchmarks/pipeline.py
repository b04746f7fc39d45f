"""Benchmark whole runs (source, frontend and backend processes over zenoh) against real time: lockstep, pipelined, live.

For the KITTI 06 clip (51 frames, 10 Hz) and the EuRoC V1_01 micro clip (95 frames, 20 Hz), runs
``zenslam run <clip> --lockstep``, ``--pipelined`` and ``--live --rate R`` (for each of ``--rates``)
as a user would and records:
- the command's wall time (process start-up included) and the streaming span, from the frontend's
  first frame to the backend's end of stream (from the stage logs' timestamps), against the
  clip's real duration (divided by the rate for live runs);
- frames tracked and skipped, keyframes sent by the frontend and processed by the backend;
- CPU seconds per process (each stage logs its own at exit; the hub is the command's total less
  the stages');
- the backend's time per keyframe for each local-mapping step (insertion, point culling,
  triangulation, fusion, local BA, keyframe culling, total: mean / median / max ms), the most
  keyframes waiting in its inbox, and the frontend's total per frame;
- ATE of the per-frame trajectory as tracked, of trajectory_final.tum (each frame at its reference
  keyframe's final pose) and of keyframes.tum (the backend's final keyframe poses).
Wall times on a shared 2-core machine: the load average before each run is recorded with it.

It ends with the verdict on "the full pipeline runs at >= 2x real time" for the pipelined KITTI
run(s) (offline, lossless) and the rate-2 live one(s): every frame tracked, every keyframe
processed, and the stream span at most half the clip's real time.

Run: ``.venv/bin/python benchmarks/pipeline.py [--data ../shared/data] [--modes lockstep pipelined live]
[--rates 1 2] [--clips kitti_06_clip euroc_v1_01_micro]`` (writes benchmarks/results/pipeline.json).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

import numpy as np

from zenslam.errors import TrajectoryError
from zenslam.runtime import environment
from zenslam.service.evaluation.metrics import evaluate
from zenslam.service.evaluation.trajectory_io import read_tum
from zenslam.service.sources import open_source

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "pipeline.json"
_STAMP = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) ")
_CPU = re.compile(r"cpu (at stream start|at stream end|at exit): user ([0-9.]+) s system ([0-9.]+) s")


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


def stage_cpu_s(run_dir: Path) -> tuple[dict[str, float], dict[str, float]]:
    """CPU seconds (user + system) per stage process: in all, and from its stream's start to its exit
    (start-up imports excluded), from the lines each stage logs."""
    total, streaming = {}, {}
    for path in sorted((run_dir / "logs").glob("*.log")):
        marks = _cpu_marks(path.read_text(errors="replace"))
        if "at exit" in marks:
            total[path.stem] = marks["at exit"]
            streaming[path.stem] = marks["at exit"] - marks.get("at stream start", 0.0)
    return total, streaming


def _cpu_marks(log: str) -> dict[str, float]:
    """CPU seconds (user + system) at each ``cpu <when>:`` line of a process's log, first of each."""
    marks: dict[str, float] = {}
    for line in log.splitlines():
        if match := _CPU.search(line):
            marks.setdefault(match.group(1), float(match.group(2)) + float(match.group(3)))
    return marks


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run_id(name: str, mode: str, rate: float) -> str:
    return f"{name}-live-x{rate:g}" if mode == "live" else f"{name}-{mode}"


def run(name: str, spec: str, mode: str, output: Path, rate: float = 1.0, config: Path | None = None) -> dict:
    """One ``zenslam run`` of ``spec`` in ``mode`` (lockstep, pipelined, or live at ``rate`` x the recorded rate); its figures."""
    run_id = _run_id(name, mode, rate)
    command = [sys.executable, "-m", "zenslam.service.cli", "run", spec, f"--{mode}", "--output", str(output),
               "--run-id", run_id, "--no-progress"]  # fmt: skip
    if mode == "live":
        command += ["--rate", f"{rate:g}"]
    if config is not None:
        command += ["--config", str(config)]
    load = os.getloadavg()
    cpu_before = _children_cpu_s()
    start = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True, timeout=1800)
    wall_s = time.perf_counter() - start
    total_cpu_s = _children_cpu_s() - cpu_before
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
    cpu, cpu_streaming = stage_cpu_s(run_dir)
    cpu["run (hub)"] = total_cpu_s - sum(cpu.values())
    hub = _cpu_marks(result.stdout + result.stderr)
    if "at stream end" in hub:
        cpu_streaming["run (hub)"] = hub["at stream end"] - hub.get("at stream start", 0.0)
    frames_in_clip = len(open_source(spec))
    return {
        "name": name,
        "mode": mode,
        "rate": rate if mode == "live" else None,
        "real_time_s": real_s,
        "command_wall_s": wall_s,
        "stream_span_s": span_s,
        "stream_span_over_real_time": span_s / real_s if span_s is not None else None,
        "frames_in_clip": frames_in_clip,
        "frames_skipped": frames_in_clip - metrics["frames"],
        "cpu_s": cpu,
        "cpu_streaming_s": cpu_streaming,
        "frames_tracked": metrics["frames"],
        "frames_ok": metrics["tracked_ok"],
        "keyframes": metrics["keyframes"],
        "backend_queue_depth_max": metrics["backend_queue_depth_max"],
        "backend_timing_ms": metrics["backend_timing"],
        "frontend_total_ms": metrics["timing"].get("total"),
        "ate_rmse_m": metrics.get("ate", {}).get("rmse_m"),
        "keyframes_ate_rmse_m": keyframes_ate,
        "final_ate_rmse_m": metrics.get("ate_final", {}).get("rmse_m"),
        "load_average_1_5_15_before": load,
    }


def _m(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.4f} m"


def _mode(r: dict) -> str:
    return r["mode"] if r["rate"] is None else f"live x{r['rate']:g}"


def print_run(r: dict) -> None:
    span = (
        f"{r['stream_span_s']:.2f} s ({r['stream_span_over_real_time']:.2f} of the real time: "
        f"{1.0 / r['stream_span_over_real_time']:.2f}x real time)" if r["stream_span_s"] else "n/a"
    )
    mode = _mode(r)
    print(
        f"{r['name']} {mode}: real time {r['real_time_s']:.2f} s, command {r['command_wall_s']:.2f} s, stream {span}; "
        f"frames {r['frames_tracked']}/{r['frames_in_clip']} ({r['frames_ok']} ok, {r['frames_skipped']} skipped), keyframes sent {r['keyframes']['sent']} "
        f"processed {r['keyframes']['processed']} (at most {r['backend_queue_depth_max']} queued); ATE {r['ate_rmse_m']:.4f} m (final {_m(r['final_ate_rmse_m'])}, keyframes {_m(r['keyframes_ate_rmse_m'])}); "
        f"load {r['load_average_1_5_15_before'][0]:.1f}"
    )
    for step, t in r["backend_timing_ms"].items():
        print(f"    backend {step:<17} mean {t['mean_ms']:7.1f}  median {t['median_ms']:7.1f}  max {t['max_ms']:7.1f} ms")
    t = r["frontend_total_ms"]
    if t:
        print(f"    frontend total            mean {t['mean_ms']:7.1f}  median {t['median_ms']:7.1f}  max {t['max_ms']:7.1f} ms")
    print("    cpu in all " + ", ".join(f"{stage} {seconds:.2f} s" for stage, seconds in r["cpu_s"].items()))
    print("    cpu from stream start " + ", ".join(f"{stage} {seconds:.2f} s" for stage, seconds in r["cpu_streaming_s"].items()))


def twice_real_time(runs: list[dict]) -> str:
    """The verdict on ">= 2x real time" from the pipelined and the rate-2 live KITTI run(s)."""
    judged = [r for r in runs if r["name"] == "kitti_06_clip" and (r["mode"] == "pipelined" or r["rate"] == 2)]
    if not judged:
        return ">= 2x real time: not measured (needs --modes pipelined, or live --rates 2, on kitti_06_clip)"
    lines = []
    for r in judged:
        span, budget = r["stream_span_s"], r["real_time_s"] / 2
        every_frame = r["frames_skipped"] == 0
        every_keyframe = r["keyframes"]["processed"] == r["keyframes"]["sent"]
        holds = every_frame and every_keyframe and span is not None and span <= budget
        lines.append(
            f">= 2x real time: {'HOLDS' if holds else 'does not hold'} (kitti {_mode(r)}: {r['frames_skipped']} frames skipped, "
            f"keyframes {r['keyframes']['processed']}/{r['keyframes']['sent']} processed, stream span "
            f"{span if span is None else round(span, 2)} s vs {budget:.2f} s budget)"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="benchmark clips root")
    parser.add_argument("--modes", nargs="+", choices=("lockstep", "pipelined", "live"),
                        default=["lockstep", "pipelined", "live"])
    parser.add_argument("--rates", nargs="+", type=float, default=[1.0, 2.0], help="live playback rates (x recorded)")
    parser.add_argument("--clips", nargs="+", choices=("kitti_06_clip", "euroc_v1_01_micro"), default=None)
    parser.add_argument("--config", type=Path, default=None, help="run configuration YAML for every run (default: defaults)")
    parser.add_argument("--repeat", type=int, default=1, help="rounds of every mode (wall times are noisy)")
    args = parser.parse_args()
    clips = {
        "kitti_06_clip": f"kitti:{args.data / 'kitti_odometry' / 'sequences' / '06'}",
        "euroc_v1_01_micro": f"euroc:{args.data / 'euroc' / 'V1_01_easy_micro'}",
    }
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, spec in clips.items():
            if args.clips and name not in args.clips:
                continue
            # Repeats interleave the modes, so each round compares them under similar machine load.
            for _ in range(args.repeat):
                for mode, rate in [(m, r) for m in args.modes for r in (args.rates if m == "live" else [1.0])]:
                    shutil.rmtree(Path(tmp) / _run_id(name, mode, rate), ignore_errors=True)
                    runs.append(run(name, spec, mode, Path(tmp), rate, args.config))
                    print_run(runs[-1])
    print(twice_real_time(runs))
    report = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "environment": environment.describe(),
        "config": f"{args.config or 'RunConfig() defaults'}; modes {args.modes}; live runs at rates {args.rates} x the recorded rate",
        "twice_real_time": twice_real_time(runs),
        "runs": runs,
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
