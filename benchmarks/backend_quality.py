"""Benchmark what the backend does to accuracy: frontend alone vs frontend + local mapping, in one process.

For each clip (KITTI 06 0-50 stereo, EuRoC V1_01 micro, and with ``--synthetic`` the synthetic
loop and figure-eight, stereo and RGB-D) two runs are made with the same configuration:
- frontend only: ``FrontendPipeline.step`` on every frame;
- with the backend, in lockstep order without the bus: ``step``; when it makes a keyframe, the
  keyframe goes through the bus codec to ``BackendNode.step`` (local mapping + gtsam local BA),
  and its ``MapUpdate`` (through the codec too) is applied with ``pipeline.apply_map_update``
  before the next frame.
Printed and written: ATE (evo, SE(3)) of the per-frame poses of both runs and of the backend's
final keyframe poses, keyframes made / left after culling, map points per keyframe, lost frames,
the frontend's and the backend's per-step times (mean / median / max ms) and the whole run's
wall time against the clip's real duration.

With ``--update-lag N`` or ``--backend-frames F [--deferred-frames D]`` the updates arrive late, as
``LaggingBackend`` models pipelined and live runs deterministically; also printed: the largest
error of a frame-to-frame motion (a late correction that moves the pose shows there).

Run: ``.venv/bin/python benchmarks/backend_quality.py [--data ../shared/data] [--synthetic]
[--only kitti] [--max-frames N] [--update-lag N | --backend-frames F [--deferred-frames D]]``
(writes benchmarks/results/backend_quality.json). ``--backend-only --only kitti --backend-frames 5
--deferred-frames 2`` reproduces what pipelined runs on the shared 2-core machine look like: ~25 of
51 frames made keyframes, local BA run on ~1 in 6.
``--only`` matches part of a clip's name: ``--synthetic --only figure_eight_rgbd`` runs that
scene's RGB-D clip alone (~7 min on the shared 2-core machine, ~6 of them with the backend).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import statistics
import time
from collections import deque
from pathlib import Path

import numpy as np

from zenslam.backend.node import BackendNode
from zenslam.frontend.node import keyframe_message
from zenslam.frontend.pipeline import FrontendConfig, FrontendPipeline
from zenslam.runtime import environment
from zenslam.schemas import codec
from zenslam.service.evaluation.metrics import EvaluationConfig, evaluate
from zenslam.backend.config import BackendConfig
from zenslam.trajectory import Trajectory

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "backend_quality.json"


def summary(values_ms: list[float]) -> dict[str, float]:
    if not values_ms:
        return {"mean": 0.0, "median": 0.0, "max": 0.0}
    return {"mean": statistics.fmean(values_ms), "median": statistics.median(values_ms), "max": max(values_ms)}


def ate_of(stamps_ns: list[int], poses: list[np.ndarray], ground_truth: Trajectory) -> dict:
    """ATE (SE(3) alignment) of a trajectory against the truth, the path length, and the Sim(3)
    alignment's scale and ATE (a scale error shows as ATE growing along a straight path)."""
    estimate = Trajectory(np.asarray(stamps_ns, np.int64), np.stack(poses))
    evaluation = evaluate(estimate, ground_truth)
    sim3 = evaluate(estimate, ground_truth, EvaluationConfig(alignment="sim3"))
    ate = evaluation.to_json()["ate"]
    return {"rmse_m": ate["rmse_m"], "max_m": ate["max_m"], "percent_of_path": ate["rmse_percent_of_path"],
            "path_length_m": evaluation.path_length_m, "sim3_rmse_m": sim3.ate.rmse_m,
            "sim3_scale": sim3.ate.scale}  # fmt: skip


def largest_jump(stamps_ns: list[int], poses: list[np.ndarray], ground_truth: Trajectory) -> dict:
    """The largest error of a motion between consecutive tracked frames (metres), and where: a late
    correction that moves the tracked pose shows here as a jump that the truth does not make."""
    index = {int(s): i for i, s in enumerate(np.asarray(ground_truth.stamps_ns))}
    worst, at = 0.0, -1
    for k in range(1, len(stamps_ns)):
        a, b = index.get(int(stamps_ns[k - 1])), index.get(int(stamps_ns[k]))
        if a is None or b is None:
            continue
        estimated = np.linalg.inv(poses[k - 1]) @ poses[k]
        true = np.linalg.inv(ground_truth.T_world_cam[a]) @ ground_truth.T_world_cam[b]
        error = float(np.linalg.norm(estimated[:3, 3] - true[:3, 3]))
        if error > worst:
            worst, at = error, k
    return {"max_m": worst, "at_stamp_ns": int(stamps_ns[at]) if at >= 0 else -1}


class LaggingBackend:
    """The backend as pipelined and live runs see it, deterministically, in frame periods: either each
    keyframe's map update (and the corrections after it) arrives ``update_lag`` frames after the
    frame that made it, every keyframe fully mapped; or (``backend_frames`` > 0) one keyframe is
    mapped at a time, each taking ``backend_frames`` frame periods (``deferred_frames`` when keyframes
    wait behind it and local mapping defers its fusion, BA and culling; by default a quarter), from
    half a period after the frame that made it; its updates arrive when it is done. Time t is the
    start of frame t."""

    def __init__(self, backend: BackendNode, update_lag: int = 0, backend_frames: float = 0.0, deferred_frames: float = 0.0) -> None:
        self.backend = backend
        self.update_lag = update_lag
        self.backend_frames = backend_frames
        self.deferred_frames = deferred_frames or backend_frames / 4.0
        self.steps: list[dict[str, float]] = []
        self._queue: deque[tuple[float, object]] = deque()  # (time sent, keyframe message)
        self._arriving: deque[tuple[float, object]] = deque()  # (time it arrives, map update)
        self._free_at = 0.0

    def send(self, frame_index: int, message) -> None:
        if self.backend_frames <= 0:
            self._arriving.extend((frame_index + 1.0 + self.update_lag, u) for u in self._step(message, 0).updates)
        else:
            self._queue.append((frame_index + 0.5, message))

    def arrived(self, now: float) -> list:
        """The map updates that have arrived by time ``now``, in order (decoded through the codec)."""
        while self._queue and max(self._free_at, self._queue[0][0]) <= now:
            start = max(self._free_at, self._queue[0][0])
            message = self._queue.popleft()[1]
            queued = sum(1 for sent, _ in self._queue if sent <= start)
            deferred_before = self.backend.mapper.totals["deferred"]
            step = self._step(message, queued)
            deferred = self.backend.mapper.totals["deferred"] > deferred_before
            self._free_at = start + (self.deferred_frames if deferred else self.backend_frames)
            self._arriving.extend((self._free_at, u) for u in step.updates)
        out = []
        while self._arriving and self._arriving[0][0] <= now:
            out.append(codec.decode_map_update(codec.encode_map_update(self._arriving.popleft()[1])))
        return out

    @property
    def keyframes_in_flight(self) -> int:
        """Keyframes sent whose answer has not arrived (what the frontend's keyframe decision sees)."""
        return len(self._queue) + sum(1 for _, u in self._arriving if u.answers_keyframe)

    def _step(self, message, queued: int):
        step = self.backend.step(message, queued=queued)
        self.steps.append(self.backend.last_timings_ms)
        return step


def run_once(frames, calibration, sensor, ground_truth: Trajectory, with_backend: bool, frontend_config: FrontendConfig,
             backend_config: BackendConfig, update_lag: int = 0, backend_frames: float = 0.0,
             deferred_frames: float = 0.0) -> dict:  # fmt: skip
    """Track every frame (images loaded beforehand), optionally with the backend: in lockstep, or
    lagging as ``LaggingBackend`` models it, the frontend's keyframe decision seeing the keyframes in
    flight, as in pipelined and live runs."""
    pipeline = FrontendPipeline(frontend_config, calibration, sensor)
    backend = BackendNode.from_config(backend_config) if with_backend else None
    lagging = LaggingBackend(backend, update_lag, backend_frames, deferred_frames) if backend is not None else None
    stamps, poses, states, frontend_ms = [], [], [], []
    n_keyframes = 0
    start = time.perf_counter()
    for frame in frames:
        in_flight = 0
        if lagging is not None:
            for update in lagging.arrived(float(frame.index)):
                pipeline.apply_map_update(update)
            in_flight = lagging.keyframes_in_flight
        out = pipeline.step(frame.index, frame.stamp_ns, frame.left, right=frame.right, depth_m=frame.depth_m,
                            keyframes_in_flight=in_flight)  # fmt: skip
        frontend_ms.append(out.timings_ms["total"])
        states.append(out.state)
        if out.T_world_cam is not None:
            stamps.append(out.stamp_ns)
            poses.append(out.T_world_cam)
        for keyframe in out.keyframes_made:
            n_keyframes += 1
            if lagging is not None:
                lagging.send(frame.index, codec.decode_keyframe(codec.encode_keyframe(keyframe_message(keyframe, calibration, sensor))))
    wall_s = time.perf_counter() - start
    result = {
        "frames": len(frames),
        "wall_s": wall_s,
        "states": {s: states.count(s) for s in ("ok", "lost", "initializing")},
        "keyframes_made": n_keyframes,
        "ate_per_frame": ate_of(stamps, poses, ground_truth),
        "largest_jump": largest_jump(stamps, poses, ground_truth),
        "frontend_total_ms": summary(frontend_ms),
    }
    if backend is not None:
        result.update(backend_report(backend, lagging.steps, ground_truth))
        backend.close()
    return result


def backend_report(backend: BackendNode, steps: list[dict[str, float]], ground_truth: Trajectory) -> dict:
    """Keyframes kept, points per keyframe, keyframe-pose ATE and per-step times of the backend."""
    bmap = backend.mapper.map
    kfs = list(bmap.keyframes.values())
    per_kf = [int(np.count_nonzero(kf.map_point_ids >= 0)) for kf in kfs]
    report = {
        "keyframes_kept": len(kfs),
        "map_points": len(bmap.points),
        "map_points_per_keyframe": len(bmap.points) / max(len(kfs), 1),
        "observations_per_keyframe": summary([float(n) for n in per_kf]),
        "backend_totals": dict(backend.mapper.totals),
        "backend_timing_ms": {key: summary([s.get(key, 0.0) for s in steps]) for key in (steps[0] if steps else {})},
    }
    if len(kfs) >= 3:
        report["ate_keyframes"] = ate_of([kf.stamp_ns for kf in kfs], [kf.T_world_cam for kf in kfs], ground_truth)
    return report


def run(name: str, source, backend_only: bool, max_frames: int | None = None, update_lag: int = 0,
        backend_frames: float = 0.0, deferred_frames: float = 0.0) -> dict:
    frames = list(itertools.islice(source, max_frames))
    ground_truth = source.ground_truth()
    frontend_config, backend_config = FrontendConfig(), BackendConfig()
    args = (frames, source.calibration, source.sensor, ground_truth)
    stamps = np.array([f.stamp_ns for f in frames], np.int64)
    real_s = float((stamps[-1] - stamps[0] + np.median(np.diff(stamps))) * 1e-9)
    result = {"name": name, "sensor": source.sensor, "real_time_s": real_s, "update_lag": update_lag,
              "backend_frames": backend_frames,
              "deferred_frames": deferred_frames, "load_before": os.getloadavg()}
    if not backend_only:
        result["frontend_only"] = run_once(*args, False, frontend_config, backend_config)
    result["with_backend"] = run_once(*args, True, frontend_config, backend_config, update_lag, backend_frames, deferred_frames)
    return result


def sources(data: Path, synthetic: bool, only: str | None):
    from zenslam.service.sources.euroc import EurocSource
    from zenslam.service.sources.kitti import KittiSource

    named = [("kitti_06_clip", lambda: KittiSource(data / "kitti_odometry" / "sequences" / "06")),
             ("euroc_v1_01_micro", lambda: EurocSource(data / "euroc" / "V1_01_easy_micro"))]  # fmt: skip
    if synthetic:
        from zenslam.service.sources.synthetic import SyntheticSource, scene_config

        for scene in ("loop", "figure_eight"):
            for sensor in ("stereo", "rgbd"):
                config = scene_config(scene, sensor=sensor)
                named.append((f"synthetic_{scene}_{sensor}", lambda c=config: SyntheticSource(c)))
    for name, make in named:
        if only is None or only in name:
            yield name, make()


def print_run(r: dict) -> None:
    print(f"{r['name']} ({r['sensor']}, real time {r['real_time_s']:.1f} s):")
    for key in ("frontend_only", "with_backend"):
        if key not in r:
            continue
        x = r[key]
        a = x["ate_per_frame"]
        line = (f"  {key:<14} ATE {a['rmse_m'] * 100:6.2f} cm ({a['percent_of_path']:.3f} % of {a['path_length_m']:.1f} m; "
                f"sim3 {a['sim3_rmse_m'] * 100:.2f} cm, scale {a['sim3_scale']:.4f})"
                f"  states {x['states']}  keyframes {x['keyframes_made']}  wall {x['wall_s']:.1f} s"
                f"\n                 largest frame-to-frame error {x['largest_jump']['max_m'] * 100:.2f} cm")  # fmt: skip
        if "keyframes_kept" in x:
            kfa = x.get("ate_keyframes", {}).get("rmse_m", float("nan"))
            line += (f"\n                 kept {x['keyframes_kept']}  points/kf {x['map_points_per_keyframe']:.0f}"
                     f"  keyframe ATE {kfa * 100:.2f} cm  totals {x['backend_totals']}")  # fmt: skip
            for step, t in x["backend_timing_ms"].items():
                line += f"\n                   {step:<17} mean {t['mean']:6.1f} median {t['median']:6.1f} max {t['max']:6.1f} ms"
        print(line)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="benchmark clips root")
    parser.add_argument("--synthetic", action="store_true", help="also run the synthetic loop and figure-eight")
    parser.add_argument("--only", default=None, help="run only the clips whose name contains this")
    parser.add_argument("--backend-only", action="store_true", help="skip the frontend-only runs")
    parser.add_argument("--max-frames", type=int, default=None, help="use only the first N frames of each clip")
    parser.add_argument("--update-lag", type=int, default=0, help="apply each map update this many frames late (0: lockstep)")
    parser.add_argument("--backend-frames", type=float, default=0.0,
                        help="a serial backend taking this many frame periods per keyframe (0: off; see LaggingBackend)")
    parser.add_argument("--deferred-frames", type=float, default=0.0,
                        help="with --backend-frames: frame periods of a keyframe whose BA is deferred (0: a quarter of --backend-frames)")
    args = parser.parse_args()
    runs = []
    for name, source in sources(args.data, args.synthetic, args.only):
        runs.append(run(name, source, args.backend_only, args.max_frames, args.update_lag, args.backend_frames, args.deferred_frames))
        print_run(runs[-1])
    report = {"machine": platform.platform(), "python": platform.python_version(), "cpu_count": os.cpu_count(),
              "environment": environment.describe(),
              "config": "FrontendConfig(), BackendConfig() defaults", "runs": runs}  # fmt: skip
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
