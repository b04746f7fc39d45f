"""Soak benchmark: a long run over the same place, lap by lap: each process's memory, the map's size, restarts.

Runs ``zenslam run synthetic:<scene>,laps=N --pipelined`` (default: the figure-eight, 20 laps of
30 s at 20 Hz, 12,001 frames) into a temporary folder and follows it as a client of its session
(``zenslam.client``). Ten frames before each lap ends it takes, for every process of the run (the
hub and its source, frontend, backend and recorder), the resident set (RSS) and the proportional
set size (PSS: pages mapped by several processes shared out among them), and asks the backend for
its map (keyframes and points). At the end it reads the run's metrics.json: ATE, the
restarts and their events.

Revisiting the same room must not grow the map without bound (keyframe culling and loop fusion
keep it flat), nor the processes' memory: the figures at the last lap are compared with those at
lap 2 (the first lap builds the map; the second is the first revisit).

Run: ``.venv/bin/python benchmarks/soak.py [--laps 20] [--scene figure_eight] [--mode pipelined]
[--config YAML] [--keep DIR]`` (writes benchmarks/results/soak.json, or ``--results PATH``). The
run folder (about 4 GB for 20 laps, most of it run.mcap) goes into a temporary folder, removed at
the end, or is kept under ``--keep DIR``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent))
from footprint import process_name, pss_bytes, rss_bytes  # noqa: E402

from zenslam.client import Client  # noqa: E402
from zenslam.service.sources import open_source  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "soak.json"
_MB = 1e6
_TARGET = 0.10  # lap N within 10% of lap 2
_MARGIN_FRAMES = 10  # frames before a lap's end at which it is sampled


class _Newest:
    """The newest frame index the run's frontend reported (a client callback: kept trivial)."""

    def __init__(self) -> None:
        self.index = -1
        self.lock = threading.Lock()

    def __call__(self, state) -> None:
        with self.lock:
            self.index = max(self.index, int(state.index))


def _processes(root: psutil.Process) -> dict[str, dict[str, float]]:
    """RSS and PSS (MB) of the run's processes by stage name (restarted stages: the living one)."""
    try:
        tree = [root, *root.children(recursive=True)]
    except psutil.Error:
        return {}
    out: dict[str, dict[str, float]] = {}
    for proc in tree:
        rss, pss = rss_bytes(proc.pid), pss_bytes(proc.pid)
        if rss is None:
            continue
        name = process_name(proc)
        if name.startswith(("python", "pid")):
            continue  # a helper such as the background global BA's worker is counted under its own name
        entry = out.setdefault(name, {"rss_mb": 0.0, "pss_mb": 0.0})
        entry["rss_mb"] += rss / _MB
        entry["pss_mb"] += (pss or 0) / _MB
    return out


def _lap_sample(lap: int, root: psutil.Process, client: Client) -> dict[str, object]:
    processes = _processes(root)
    snapshot = client.query_map(timeout_s=60.0)
    sample: dict[str, object] = {
        "lap": lap,
        "t_s": time.monotonic(),
        "processes": processes,
        "rss_sum_mb": sum(p["rss_mb"] for p in processes.values()),
        "pss_sum_mb": sum(p["pss_mb"] for p in processes.values()),
    }
    if snapshot is not None:
        sample["keyframes"] = len(snapshot.keyframes.keyframe_ids)
        sample["points"] = len(snapshot.point_ids)
        sample["keyframes_processed"] = int(snapshot.keyframes.keyframes_processed)
    return sample


def _ratio(last: dict, second: dict, key: str) -> float | None:
    a, b = last.get(key), second.get(key)
    return None if not a or not b else float(a) / float(b)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--laps", type=int, default=20)
    parser.add_argument("--scene", default="figure_eight", help="synthetic scene with laps: loop, figure_eight, corridor")
    parser.add_argument("--mode", choices=("pipelined", "lockstep", "live"), default="pipelined")
    parser.add_argument("--config", type=Path, default=None, help="run config YAML")
    parser.add_argument("--keep", type=Path, default=None, help="keep the run folder under this folder")
    parser.add_argument("--results", type=Path, default=RESULTS)
    args = parser.parse_args()

    spec = f"synthetic:{args.scene},laps={args.laps}"
    source = open_source(spec)
    frames = len(source)
    frames_per_lap = (frames - 1) // args.laps
    # The run folder is large (run.mcap and the rerun files: about 4 GB for 20 figure-eight laps): removed unless --keep.
    output = args.keep or Path(tempfile.mkdtemp(prefix="zenslam-soak-"))
    run_id = f"soak-{os.getpid()}"
    command = [sys.executable, "-m", "zenslam.service.cli", "run", spec, f"--{args.mode}", "--output", str(output),
               "--run-id", run_id, "--no-progress"]  # fmt: skip
    if args.config is not None:
        command += ["--config", str(args.config)]
    print(f"soak: {spec} ({frames} frames, {frames_per_lap} per lap), {args.mode}, into {output / run_id}", flush=True)
    started = time.monotonic()
    log = open(output / f"{run_id}.log", "w")
    popen = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
    root = psutil.Process(popen.pid)
    newest = _Newest()
    samples: list[dict[str, object]] = []
    with Client.for_run(output / run_id, timeout_s=120.0) as client:
        client.on_state(newest)
        lap_seen = 0
        while popen.poll() is None:
            with newest.lock:
                index = newest.index
            # A lap is sampled ``_MARGIN_FRAMES`` before its end: the last one while the backend still answers.
            lap = (index + _MARGIN_FRAMES) // frames_per_lap + 1 if index >= 0 else 0
            if lap > lap_seen and lap >= 2:
                sample = _lap_sample(lap - 1, root, client)  # lap - 1 has just been completed
                sample["t_s"] = round(float(sample["t_s"]) - started, 1)
                samples.append(sample)
                procs = " ".join(f"{n} {p['rss_mb']:.0f}" for n, p in sorted(sample["processes"].items()))  # type: ignore[union-attr]
                print(
                    f"lap {lap - 1:3d} at {sample['t_s']:7.1f} s: keyframes {sample.get('keyframes', '?'):>5} points "
                    f"{sample.get('points', '?'):>6} | RSS MB {procs} | sum {sample['rss_sum_mb']:.0f} (PSS {sample['pss_sum_mb']:.0f})",
                    flush=True,
                )  # fmt: skip
            lap_seen = max(lap_seen, lap)
            time.sleep(0.5)
    log.close()
    wall_s = time.monotonic() - started
    metrics_path = output / run_id / "metrics.json"
    metrics = json.loads(metrics_path.read_text()) if metrics_path.exists() else {}
    run = metrics.get("run", {})
    result: dict[str, object] = {
        "spec": spec, "mode": args.mode, "laps": args.laps, "frames": frames, "frames_per_lap": frames_per_lap,
        "exit_code": popen.returncode, "wall_s": round(wall_s, 1), "machine": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(), "samples": samples,
        "ate_m": metrics.get("ate", {}).get("rmse_m"), "tracked_ok": metrics.get("tracked_ok"),
        "restarts": run.get("restarts"), "restart_events": run.get("restart_events"), "loops": metrics.get("loops", {}).get("accepted"),
    }  # fmt: skip
    second = next((s for s in samples if s["lap"] == 2), None)
    if second is not None and samples and samples[-1]["lap"] > 2:
        last = samples[-1]
        ratios = {key: _ratio(last, second, key) for key in ("keyframes", "points", "rss_sum_mb", "pss_sum_mb")}
        for name, proc in last["processes"].items():  # type: ignore[union-attr]
            before = second["processes"].get(name)  # type: ignore[union-attr]
            if before:
                ratios[f"rss_{name}"] = proc["rss_mb"] / before["rss_mb"]
        result["last_over_lap2"] = ratios
        result["within_target"] = all(r is not None and r <= 1 + _TARGET for r in ratios.values())
        print(f"lap {last['lap']} / lap 2: " + ", ".join(f"{k} {v:.3f}" for k, v in ratios.items() if v is not None))
        print(f"within {_TARGET:.0%} of lap 2: {result['within_target']}")
    print(f"exit {popen.returncode}, {wall_s:.0f} s; ATE {result['ate_m']}; restarts {result['restarts']}; loops {result['loops']}")
    if args.keep is None:
        shutil.rmtree(output, ignore_errors=True)
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps(result, indent=1))
    print(f"wrote {args.results}")


if __name__ == "__main__":
    main()
