"""Restart benchmark: a stage SIGKILLed at chosen frames of a lockstep run, beside the unharmed run
and beside the same run with only that one frame dropped.

For each frame F of ``--frames`` it runs ``zenslam run SCENE`` three ways (rerun and the recorder
off, lockstep): unharmed (once for all F), with frame F dropped by the source (``source.faults``,
kind drop), and with the ``--stage`` process SIGKILLed as soon as frontend/state reports frame F
(the run follows as a ``zenslam.client`` of the run's session, so the kill lands at a frame, not at
a wall-clock time that depends on the machine's speed). The supervisor restarts the stage.

Why the dropped frame: lockstep output is deterministic, but the trajectory as tracked (before
loop closure) drifts differently after any small change of its input. The dropped-frame runs
measure how much one missing frame at F moves the ATE; a restart that loses nothing should move it
no more than that. For the backend, a restart rebuilds the map from its journal and the trajectory
should be byte-identical to the unharmed one (``same_trajectory``).

Printed per run: exit code, restarts and the frame tracking resumed at, frames lost, ATE as tracked
(``trajectory.tum``) and final (``trajectory_final.tum``), each against the unharmed run.

Run: ``.venv/bin/python benchmarks/restart.py [--stage frontend] [--frames 35 80 117 134 168]
[--scene synthetic:loop] [--keep DIR]`` (writes benchmarks/results/restart.json, or ``--results
PATH``). Each run of the default scene takes about a minute here.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent))
from footprint import process_name  # noqa: E402

from zenslam.client import Client  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "restart.json"
ZENSLAM = Path(sys.executable).with_name("zenslam")
LEAN_YAML = "rerun: {enabled: false}\nrecorder: {enabled: false}\n"


class _ReachedFrame:
    """Set once frontend/state reports frame ``index`` or later (a client callback: kept trivial)."""

    def __init__(self, index: int) -> None:
        self.index = index
        self.event = threading.Event()

    def __call__(self, state) -> None:
        if int(state.index) >= self.index:
            self.event.set()


def _stage_process(root: psutil.Process, stage: str) -> psutil.Process | None:
    for proc in root.children(recursive=True):
        if process_name(proc) == stage:
            return proc
    return None


def _run(scene: str, work: Path, run_id: str, yaml: str, kill: tuple[str, int] | None) -> dict[str, object]:
    """One ``zenslam run``; ``kill``: (stage, frame) to SIGKILL the stage at. Its figures."""
    config = work / f"{run_id}.yaml"
    config.write_text(yaml)
    command = [str(ZENSLAM), "run", scene, "--config", str(config), "--output", str(work), "--run-id", run_id, "--no-progress"]
    started = time.monotonic()
    killed_at = None
    with open(work / f"{run_id}.log", "w") as log, subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT) as proc:
        try:
            if kill is not None:
                stage, frame = kill
                reached = _ReachedFrame(frame)
                with Client.for_run(work / run_id) as client:  # followed until the run ends
                    client.on_state(reached)
                    while proc.poll() is None and not reached.event.wait(0.05):
                        pass
                    target = _stage_process(psutil.Process(proc.pid), stage) if proc.poll() is None else None
                    if target is not None:
                        target.send_signal(signal.SIGKILL)
                        killed_at = frame
                    proc.wait()
        except BaseException:
            proc.send_signal(signal.SIGINT)  # the run writes its outputs and stops its stages
            raise
    run_dir = work / run_id
    metrics = json.loads((run_dir / "metrics.json").read_text())
    events = metrics["run"].get("restart_events") or []
    trajectory = run_dir / "trajectory.tum"
    return {
        "run_id": run_id,
        "exit": proc.returncode,
        "wall_s": round(time.monotonic() - started, 1),
        "killed_at_frame": killed_at,
        "restarts": metrics["run"]["restarts"],
        "resumed_at_frame": events[0].get("relocalised_at") if events else None,
        "frames_lost": sum(int(e.get("frames_lost") or 0) for e in events),
        "keyframes": metrics["keyframes"]["processed"],
        "ate_mm": metrics["ate"]["rmse_m"] * 1e3,
        "ate_final_mm": metrics["ate_final"]["rmse_m"] * 1e3,
        "trajectory_sha256": hashlib.sha256(trajectory.read_bytes()).hexdigest() if trajectory.exists() else None,
    }


def _drop_yaml(frame: int) -> str:
    return LEAN_YAML + f"source:\n  faults: [{{kind: drop, first_frame: {frame}, last_frame: {frame}}}]\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stage", choices=("frontend", "backend"), default="frontend")
    parser.add_argument("--frames", type=int, nargs="+", default=[35, 80, 117, 134, 168])
    parser.add_argument("--scene", default="synthetic:loop")
    parser.add_argument("--no-drop", action="store_true", help="skip the dropped-frame runs")
    parser.add_argument("--keep", type=Path, default=None, help="keep the run folders here (default: a temporary folder)")
    parser.add_argument("--results", type=Path, default=RESULTS)
    args = parser.parse_args()

    work = args.keep or Path(tempfile.mkdtemp(prefix="zenslam-restart-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        unharmed = _run(args.scene, work, "unharmed", LEAN_YAML, None)
        rows = []
        for frame in args.frames:
            row = {"frame": frame, "restart": _run(args.scene, work, f"kill{frame}", LEAN_YAML, (args.stage, frame))}
            if not args.no_drop:
                row["drop"] = _run(args.scene, work, f"drop{frame}", _drop_yaml(frame), None)
            rows.append(row)
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)

    def rel(value: float, key: str) -> float:
        return value / float(unharmed[key]) - 1.0

    print(f"{args.scene}, {args.stage} SIGKILLed at a frame; unharmed: ATE {unharmed['ate_mm']:.2f} mm, final {unharmed['ate_final_mm']:.2f} mm")
    print("frame | restart: exit restarts resumed lost  ATE mm (vs unharmed)  final mm (vs) same | drop: ATE mm (vs)  final mm (vs)")
    for row in rows:
        r = row["restart"]
        r["same_trajectory"] = r["trajectory_sha256"] == unharmed["trajectory_sha256"]
        line = (
            f"{row['frame']:5d} | {r['exit']:4d} {r['restarts']:8d} {'-' if r['resumed_at_frame'] is None else r['resumed_at_frame']:>7} {r['frames_lost']:4d}  "
            f"{r['ate_mm']:6.2f} ({rel(r['ate_mm'], 'ate_mm'):+6.1%})  {r['ate_final_mm']:6.2f} ({rel(r['ate_final_mm'], 'ate_final_mm'):+6.1%})"
            f"  {'yes' if r['same_trajectory'] else 'no':>4}"
        )
        if "drop" in row:
            d = row["drop"]
            line += (
                f" | {d['ate_mm']:6.2f} ({rel(d['ate_mm'], 'ate_mm'):+6.1%})  {d['ate_final_mm']:6.2f} "
                f"({rel(d['ate_final_mm'], 'ate_final_mm'):+6.1%})"
            )
        print(line)
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps({
        "scene": args.scene, "stage": args.stage, "machine": platform.processor() or platform.machine(),
        "unharmed": unharmed, "rows": rows,
    }, indent=2))  # fmt: skip
    print(f"wrote {args.results}")


if __name__ == "__main__":
    main()
