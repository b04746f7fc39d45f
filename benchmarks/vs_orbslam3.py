"""Benchmark zenslam against ORB-SLAM3 (through the pyorbslam3 bindings) on the same clips in the same run.

For each clip and round, interleaved (the order of the two systems alternates between rounds, so
both see similar machine load):
- zenslam runs as a user runs it, ``zenslam run SPEC --lockstep`` (``--pipelined`` with the flag),
  as a whole command: its wall time, ATE of the tracked trajectory (``ate``) and of the final one
  (``ate_final``), the frontend's total per frame (``timing.total.median_ms``) and the backend's per
  keyframe (``backend_timing.total.median_ms``) from the run folder's metrics.json, and each
  process's peak RSS (VmHWM, sampled by benchmarks/footprint.py's ``run_sampled``): their sum and
  the largest; and each process's peak PSS (the largest sample; pages the stages share, such as
  their libraries, shared out among them) and their sum, ``peak_pss_sum_mb``;
- ORB-SLAM3 runs in a child process (a crash in the native library, a segfault included, ends only
  the child; its peak RSS is its own VmHWM, its peak PSS ``peak_pss_mb`` the sampler's). It reads the frames through zenslam's sources (the same
  rectified images, the synthetic scenes rendered the same way), tracks them with ``track_stereo``,
  ``track_rgbd`` or ``track_monocular`` (the call timed per frame), and saves its trajectory. It is
  given zenslam's vocabulary in DBoW2 text and an ORB-SLAM2-style settings file written here from
  the clip's calibration, with zenslam's ORB parameters and close-depth threshold (ORB-SLAM3's own
  new-format KITTI files crash pyorbslam3 0.1.1 at start-up, upstream issue #507). Its ATE is
  computed by zenslam's evaluation code (SE(3) alignment, Sim(3) for mono) against the same ground
  truth: of the poses as tracked (state OK) and of its saved trajectory (each frame composed with its
  reference keyframe's final pose, as zenslam's trajectory_final.tum).
Frames go to ORB-SLAM3 at the clip's rate, as ORB-SLAM3's example programs feed them: it is a
real-time system whose local mapping runs beside tracking, and a monocular keyframe is made only
while local mapping is idle (``--orbslam3-rate R``: R times the recorded rate, 0 as fast as it
takes them). Its wall time is then at least the clip's duration; the CPU seconds of each run
(``getrusage`` of the finished children: zenslam's command with all its processes, ORB-SLAM3's
child) compare the work whatever the pace. ATE ratios are given only where both systems tracked
most of the clip. If pyorbslam3 is missing, does not import, or crashes, one line says why and
zenslam's half still runs.

pyorbslam3 is GPL-3.0: it is the ``bench`` extra (``pip install -e '.[bench]'``), never a
dependency of zenslam, and only this script's child process imports it.

Run: ``.venv/bin/python benchmarks/vs_orbslam3.py [--rounds 3] [--clips kitti06_stereo kitti06_mono ...]
[--pipelined] [--orbslam3-rate 1] [--orbslam3-n-features N] [--config YAML] [--data ../shared/data]
[--keep DIR]`` (writes benchmarks/results/vs_orbslam3.json).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.metadata
import importlib.util
import json
import os
import platform
import resource
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.frontend.orb_extractor import OrbConfig
from zenslam.geometry import quat_wxyz_to_R
from zenslam.runtime import environment
from zenslam.service.sources import Source, open_source
from zenslam.trajectory import Trajectory

from footprint import run_sampled, vm_hwm_bytes  # the footprint benchmark's samplers (benchmarks/ is on sys.path)

# The ORB-SLAM3 child process imports this module too: what only the parent needs (the run
# configuration, evaluation, vocabulary files) is imported where it is used, so that the child's
# peak RSS is ORB-SLAM3's and the frames', little else.
if TYPE_CHECKING:
    from zenslam.service.run_config import RunConfig

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "vs_orbslam3.json"
_MB = 1e6
_CHILD_FAILED_IMPORT = 3  # exit code of the child when pyorbslam3 does not import
_REASON_PREFIX = "vs_orbslam3: "  # the child's last stderr line starting with this says why it failed
_MIN_TRACKED_SHARE = 0.9  # ATE ratios only where both systems tracked at least this share of the frames
_VIEWER = {  # ORB-SLAM2's KITTI stereo viewer entries; the viewer is off, but the map drawer reads them
    "KeyFrameSize": 0.6, "KeyFrameLineWidth": 2, "GraphLineWidth": 1, "PointSize": 2, "CameraSize": 0.7,
    "CameraLineWidth": 3, "ViewpointX": 0, "ViewpointY": -100, "ViewpointZ": -0.1, "ViewpointF": 2000,
}  # fmt: skip


@dataclass(frozen=True)
class Clip:
    """A benchmark clip: a zenslam source spec (``{data}`` is the clips' root) played as ``sensor``."""

    spec: str
    sensor: SensorKind | None = None  # None: the source's own

    def resolved(self, data: Path) -> str:
        return self.spec.format(data=data)


CLIPS = {
    "kitti06_stereo": Clip("kitti:{data}/kitti_odometry/sequences/06"),
    "kitti06_mono": Clip("kitti:{data}/kitti_odometry/sequences/06", "mono"),
    "euroc_micro_stereo": Clip("euroc:{data}/euroc/V1_01_easy_micro"),
    "loop_stereo": Clip("synthetic:loop/stereo"),
    "loop_rgbd": Clip("synthetic:loop/rgbd"),
    "corridor_stereo": Clip("synthetic:corridor/stereo"),  # 901 frames of 640x480 at 10 Hz, a loop
}


def _number(value: float) -> str:
    """A settings value as OpenCV's YAML reads it back: shortest form, always with a decimal point."""
    text = f"{value:.10g}"
    return text if any(c in text for c in ".e") else f"{text}.0"


def orbslam2_settings_text(
    calibration: PinholeCalibration,
    sensor: SensorKind,
    fps: float,
    orb: OrbConfig,
    th_depth_baselines: float,
    depth_map_factor: float = 1.0,
) -> str:
    """An ORB-SLAM2-style (old format, no ``File.version``) settings file for rectified images.

    ``calibration`` in pixels (baseline in metres, written as ``Camera.bf`` = baseline x fx) for
    stereo/RGB-D; ``fps`` frames per second; ``th_depth_baselines`` the close/far threshold in
    baselines (``ThDepth``); ``depth_map_factor`` depth-image units per metre (1 for metric float depth).
    """
    lines = [
        "%YAML:1.0",
        "# ORB-SLAM2-style settings for rectified, undistorted images (written by benchmarks/vs_orbslam3.py)",
        'Camera.type: "PinHole"',
        *(f"Camera.{name}: {_number(getattr(calibration, name))}" for name in ("fx", "fy", "cx", "cy")),
        *(f"Camera.{name}: 0.0" for name in ("k1", "k2", "p1", "p2")),
        f"Camera.width: {calibration.width}",
        f"Camera.height: {calibration.height}",
        f"Camera.fps: {_number(fps)}",
    ]
    if sensor != "mono":
        lines += [f"Camera.bf: {_number(calibration.bf)}"]
    lines += ["Camera.RGB: 1"]
    if sensor != "mono":
        lines += [f"ThDepth: {_number(th_depth_baselines)}"]
    if sensor == "rgbd":
        lines += [f"DepthMapFactor: {_number(depth_map_factor)}"]
    lines += [
        f"ORBextractor.nFeatures: {orb.n_features}",
        f"ORBextractor.scaleFactor: {_number(orb.scale_factor)}",
        f"ORBextractor.nLevels: {orb.n_levels}",
        f"ORBextractor.iniThFAST: {orb.ini_fast_threshold}",
        f"ORBextractor.minThFAST: {orb.min_fast_threshold}",
        *(f"Viewer.{name}: {value}" for name, value in _VIEWER.items()),
    ]
    return "\n".join(lines) + "\n"


def frame_rate(stamps_ns: np.ndarray) -> float:
    """The clip's camera rate, frames per second rounded to a whole number (ORB-SLAM's Camera.fps)."""
    return float(max(1, round(1e9 / float(np.median(np.diff(np.asarray(stamps_ns, dtype=np.int64)))))))


def export_vocabulary(path: Path, source: Path | None = None) -> Path:
    """Write zenslam's vocabulary (``source``; None: the default one) to ``path`` in DBoW2 text."""
    from zenslam.vocabulary import load_vocabulary, save_vocabulary

    return save_vocabulary(load_vocabulary(source), path)


def read_orbslam3_trajectory(path: Path, stamp0_ns: int, stamps_ns: np.ndarray) -> Trajectory:
    """ORB-SLAM3's SaveTrajectoryEuRoC file (``1e9 * t  tx ty tz qx qy qz qw``, T_world_cam) as a Trajectory.

    ``t`` is what the frames were tracked with: seconds since ``stamp0_ns``; each line takes the
    stamp of ``stamps_ns`` (the frames') nearest to it. A frame tracking lost without being flagged
    LOST (RECENTLY_LOST) repeats the previous line, stamp included: only the first of those is kept.
    """
    rows = np.loadtxt(path, ndmin=2) if path.stat().st_size else np.empty((0, 8))
    if len(rows):
        rows = rows[np.concatenate(([True], np.diff(rows[:, 0]) > 0))]
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    fed_ns = stamps_ns - stamp0_ns
    nearest = np.abs(rows[:, :1] - fed_ns[None, :]).argmin(axis=1) if len(rows) else np.empty(0, dtype=np.int64)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    for pose, row in zip(poses, rows):
        pose[:3, :3] = quat_wxyz_to_R(row[[7, 4, 5, 6]] / np.linalg.norm(row[4:8]))
        pose[:3, 3] = row[1:4]
    return Trajectory(stamps_ns=stamps_ns[nearest], T_world_cam=poses)


def _line_count(path: Path) -> int | None:
    """Poses in a trajectory file (its lines that are not comments), None if there is no such file."""
    if not path.exists():
        return None
    return sum(1 for line in path.read_text().splitlines() if line.strip() and not line.startswith("#"))


def ratio(numerator: float | None, denominator: float | None) -> float | None:
    if numerator is None or denominator in (None, 0):
        return None
    return numerator / denominator


def median_over_rounds(rounds: list[dict], key: str) -> float | None:
    values = [r[key] for r in rounds if r.get(key) is not None]
    return float(np.median(values)) if values else None


# ---------------------------------------------------------------- ORB-SLAM3 child process


def _own_peak_rss_mb() -> float:
    """This process's peak resident set so far (VmHWM: ru_maxrss would carry the parent's over the exec), MB."""
    return (vm_hwm_bytes(os.getpid()) or 0) / _MB


def orbslam3_child(request_path: Path) -> None:
    """Track a clip with pyorbslam3 and write what happened to the request's ``result`` file."""
    request = json.loads(request_path.read_text())
    try:
        import pyorbslam3
    except Exception as exc:  # an ImportError, or an OSError from a native library the wheel needs
        print(f"{_REASON_PREFIX}pyorbslam3 does not import: {type(exc).__name__}: {exc}", file=sys.stderr)
        sys.exit(_CHILD_FAILED_IMPORT)
    sensor = request["sensor"]
    source = open_source(request["spec"], sensor)
    kinds = {"stereo": pyorbslam3.Sensor.STEREO, "rgbd": pyorbslam3.Sensor.RGBD, "mono": pyorbslam3.Sensor.MONOCULAR}
    rss_before_mb = _own_peak_rss_mb()
    start = time.perf_counter()
    slam = pyorbslam3.Slam(request["vocabulary"], request["settings"], kinds[sensor], use_viewer=False)
    load_s = time.perf_counter() - start
    stamp0_ns = int(source.stamps_ns()[0])
    track_ms, states, tracked_stamps, tracked_poses = [], [], [], []
    start = time.perf_counter()
    for frame in source:
        t_s = (frame.stamp_ns - stamp0_ns) * 1e-9
        if request["rate"] > 0:
            time.sleep(max(0.0, start + t_s / request["rate"] - time.perf_counter()))
        before = time.perf_counter()
        if sensor == "stereo":
            result = slam.track_stereo(frame.left, frame.right, t_s)
        elif sensor == "rgbd":
            result = slam.track_rgbd(frame.left, frame.depth_m, t_s)
        else:
            result = slam.track_monocular(frame.left, t_s)
        track_ms.append((time.perf_counter() - before) * 1e3)
        states.append(result.state.name)
        if result.ok:
            tracked_stamps.append(frame.stamp_ns)
            tracked_poses.append(np.asarray(result.pose_wc, dtype=np.float64))
    stream_s = time.perf_counter() - start
    slam.shutdown()
    out = Path(request["result"])
    slam.save_trajectory_euroc(str(out.with_suffix(".final.txt")))
    slam.save_keyframe_trajectory_euroc(str(out.with_suffix(".keyframes.txt")))
    np.savez(out.with_suffix(".tracked.npz"), stamps_ns=np.asarray(tracked_stamps, dtype=np.int64),
             T_world_cam=np.asarray(tracked_poses).reshape(-1, 4, 4))  # fmt: skip
    out.write_text(json.dumps({
        "track_ms": track_ms, "states": states, "stamp0_ns": stamp0_ns, "load_s": load_s, "stream_s": stream_s,
        "rss_before_start_mb": rss_before_mb, "peak_rss_mb": _own_peak_rss_mb(),
    }))  # fmt: skip


# ---------------------------------------------------------------- the two halves


def run_measured(command: list[str]) -> tuple[dict[str, int], dict[str, int], float, float, subprocess.CompletedProcess]:
    """Run ``command`` with benchmarks/footprint.py's sampler: (peak RSS bytes per process, peak PSS
    bytes per process (the largest sample), wall s, CPU s (user + system of it and every descendant
    it waited for), result)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    sampled = run_sampled(command, interval_s=0.2)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return sampled.peak_rss, sampled.peak_pss, sampled.wall_s, cpu_s, sampled.result


def describe_failure(result: subprocess.CompletedProcess) -> str:
    """One line on why a child process failed: its signal, or its own last reason line."""
    if result.returncode < 0:
        try:
            name = signal.Signals(-result.returncode).name
        except ValueError:
            name = f"signal {-result.returncode}"
        return f"ORB-SLAM3 crashed ({name})"
    reasons = [line for line in result.stderr.splitlines() if line.startswith(_REASON_PREFIX)]
    if reasons:
        return reasons[-1][len(_REASON_PREFIX):]
    tail = (result.stderr.strip().splitlines() or result.stdout.strip().splitlines() or ["no output"])[-1]
    return f"exit code {result.returncode}: {tail[:200]}"


def ate_of(estimate: Trajectory | None, ground_truth: Trajectory | None, sensor: str) -> dict | None:
    """ATE RMSE (m) and matched poses of ``estimate``, aligned as zenslam aligns a run of ``sensor``."""
    from zenslam.errors import TrajectoryError
    from zenslam.service.evaluation.metrics import EvaluationConfig, evaluate
    from zenslam.service.run_output import evaluation_config_for

    if estimate is None or ground_truth is None or len(estimate) == 0:
        return None
    try:
        evaluation = evaluate(estimate, ground_truth, evaluation_config_for(EvaluationConfig(), sensor))
    except TrajectoryError as exc:
        return {"rmse_m": None, "error": str(exc)}
    return {"rmse_m": evaluation.ate.rmse_m, "matched_poses": evaluation.ate.matched_poses}


def run_orbslam3(spec: str, source: Source, files: dict[str, Path], work: Path, rate: float, tag: str) -> dict:
    """One ORB-SLAM3 run on ``spec`` (opened as ``source``) in a child process: its figures, or ``{"error": why}``."""
    sensor = source.sensor
    request = work / f"{tag}.request.json"
    result_file = work / f"{tag}.result.json"
    request.write_text(json.dumps({"spec": spec, "sensor": sensor, "rate": rate, "result": str(result_file),
                                   "vocabulary": str(files["vocabulary"]), "settings": str(files["settings"])}))  # fmt: skip
    command = [sys.executable, str(Path(__file__).resolve()), "--orbslam3-child", str(request)]
    peaks, pss_peaks, wall_s, cpu_s, result = run_measured(command)
    (work / f"{tag}.log").write_text(result.stdout + result.stderr)
    if result.returncode != 0:
        return {"error": describe_failure(result), "import_failed": result.returncode == _CHILD_FAILED_IMPORT}
    child = json.loads(result_file.read_text())
    ground_truth = source.ground_truth()
    with np.load(result_file.with_suffix(".tracked.npz")) as tracked:
        as_tracked = Trajectory(tracked["stamps_ns"], tracked["T_world_cam"]) if len(tracked["stamps_ns"]) else None
    final = read_orbslam3_trajectory(result_file.with_suffix(".final.txt"), child["stamp0_ns"], source.stamps_ns())
    ate, ate_final = ate_of(as_tracked, ground_truth, sensor), ate_of(final, ground_truth, sensor)
    keyframes_file = result_file.with_suffix(".keyframes.txt")
    return {
        "keyframes": _line_count(keyframes_file),  # its saved keyframe trajectory: the keyframes left after culling
        "ate_m": (ate or {}).get("rmse_m"),
        "ate_final_m": (ate_final or {}).get("rmse_m"),
        "tracked_ok": sum(s == "OK" for s in child["states"]),
        "frames": len(child["states"]),
        "tracking_median_ms": float(np.median(child["track_ms"])),
        "wall_s": wall_s,
        "cpu_s": cpu_s,
        "stream_s": child["stream_s"],
        "start_s": child["load_s"],
        "peak_rss_mb": child["peak_rss_mb"] or max(peaks.values(), default=0) / _MB,
        "peak_pss_mb": max(pss_peaks.values(), default=0) / _MB,  # the child's, sampled
        "rss_before_orbslam3_mb": child["rss_before_start_mb"],
        "evaluation": {"ate": ate, "ate_final": ate_final},
    }


def run_zenslam(spec: str, sensor: str | None, work: Path, mode: str, config: Path | None, tag: str) -> dict:
    """One ``zenslam run`` command: its figures from metrics.json, wall time and per-process peak RSS."""
    command = [sys.executable, "-m", "zenslam.service.cli", "run", spec, f"--{mode}", "--run-id", tag,
               "--output", str(work), "--no-progress"]  # fmt: skip
    if sensor is not None:
        command += ["--sensor", sensor]
    if config is not None:
        command += ["--config", str(config)]
    peaks, pss_peaks, wall_s, cpu_s, result = run_measured(command)
    (work / f"{tag}.log").write_text(result.stdout + result.stderr)
    if result.returncode != 0:
        return {"error": f"zenslam run failed (exit {result.returncode}): {result.stderr.strip().splitlines()[-1:]}"}
    metrics = json.loads((work / tag / "metrics.json").read_text())
    return {
        "ate_m": (metrics.get("ate") or {}).get("rmse_m"),
        "ate_final_m": (metrics.get("ate_final") or {}).get("rmse_m"),
        "tracked_ok": metrics.get("tracked_ok"),
        "frames": metrics.get("frames"),
        "tracking_median_ms": metrics["timing"].get("total", {}).get("median_ms"),
        "backend_median_ms_per_keyframe": metrics["backend_timing"].get("total", {}).get("median_ms"),
        # keyframes.tum holds the keyframes left after culling, as ORB-SLAM3's saved keyframe trajectory
        "keyframes": _line_count(work / tag / "keyframes.tum"),
        "keyframes_made": (metrics.get("keyframes") or {}).get("sent"),
        "wall_s": wall_s,
        "cpu_s": cpu_s,
        "peak_rss_sum_mb": sum(peaks.values()) / _MB,
        "peak_rss_max_process_mb": max(peaks.values(), default=0) / _MB,
        "peak_rss_per_process_mb": {name: round(peak / _MB, 1) for name, peak in sorted(peaks.items())},
        # PSS shares the pages several processes map (the libraries every stage loads) out among them
        "peak_pss_sum_mb": sum(pss_peaks.values()) / _MB,
        "peak_pss_per_process_mb": {name: round(peak / _MB, 1) for name, peak in sorted(pss_peaks.items())},
    }


def prepare_orbslam3_inputs(
    name: str, source: Source, config: RunConfig, n_features: int | None, work: Path, vocabulary: Path
) -> dict[str, Path]:
    """The vocabulary and the clip's settings file ORB-SLAM3 is started with: zenslam's ORB values
    (``n_features``: another number of features per image, None: zenslam's)."""
    settings = work / f"{name}.orbslam2.yaml"
    orb = config.frontend.orb if n_features is None else dataclasses.replace(config.frontend.orb, n_features=n_features)
    settings.write_text(orbslam2_settings_text(
        source.calibration, source.sensor, frame_rate(source.stamps_ns()), orb,
        config.frontend.keyframe.close_depth_baselines,
    ))  # fmt: skip
    return {"vocabulary": vocabulary, "settings": settings}


# ---------------------------------------------------------------- report

_COLUMNS = (("ate_m", "ATE m", "{:.4f}"), ("ate_final_m", "final m", "{:.4f}"), ("tracked_ok", "ok", "{:.0f}"),
            ("tracking_median_ms", "track ms", "{:.1f}"), ("wall_s", "wall s", "{:.1f}"), ("cpu_s", "CPU s", "{:.1f}"),
            ("peak_rss_mb", "peak RSS MB", "{:.0f}"), ("peak_pss_mb", "peak PSS MB", "{:.0f}"),
            ("keyframes", "keyframes", "{:.0f}"))  # fmt: skip


def summarise(clip: dict) -> None:
    """Medians over the rounds per system, and the ratios zenslam / ORB-SLAM3 of those medians."""
    for system in ("zenslam", "orbslam3"):
        rounds = [r for r in clip[system]["rounds"] if "error" not in r]
        keys = {k for r in rounds for k, v in r.items() if isinstance(v, (int, float))}
        clip[system]["median"] = {k: median_over_rounds(rounds, k) for k in sorted(keys)}
    z, o = clip["zenslam"]["median"], clip["orbslam3"]["median"]
    z_rss = z.get("peak_rss_sum_mb")
    # An ATE over a few frames, or over frames of two maps, is no measure of accuracy: ATEs are
    # compared only where both systems tracked most of the clip.
    comparable = all(
        (m.get("tracked_ok") or 0) >= _MIN_TRACKED_SHARE * (m.get("frames") or np.inf) for m in (z, o)
    )
    clip["ratio_zenslam_over_orbslam3"] = {
        "ate_m": ratio(z.get("ate_m"), o.get("ate_m")) if comparable else None,
        "ate_final_m": ratio(z.get("ate_final_m"), o.get("ate_final_m")) if comparable else None,
        "tracking_median_ms": ratio(z.get("tracking_median_ms"), o.get("tracking_median_ms")),
        "wall_s": ratio(z.get("wall_s"), o.get("wall_s")),
        "cpu_s": ratio(z.get("cpu_s"), o.get("cpu_s")),
        "peak_rss_mb": ratio(z_rss, o.get("peak_rss_mb")),  # zenslam's: the sum of its processes' peaks
        "peak_pss_mb": ratio(z.get("peak_pss_sum_mb"), o.get("peak_pss_mb")),  # likewise
        "keyframes": ratio(z.get("keyframes"), o.get("keyframes")),
    }


def print_table(report: dict) -> None:
    header = f"{'clip':<20} {'system':<9}" + "".join(f" {title:>11}" for _, title, _ in _COLUMNS) + f" {'BE ms/kf':>9}"
    print(header)
    print("-" * len(header))
    for name, clip in report["clips"].items():
        for system in ("zenslam", "orbslam3"):
            median = clip[system].get("median", {})
            values = {**median, "peak_rss_mb": median.get("peak_rss_mb", median.get("peak_rss_sum_mb")),
                      "peak_pss_mb": median.get("peak_pss_mb", median.get("peak_pss_sum_mb"))}
            cells = "".join(f" {fmt.format(values[k]) if values.get(k) is not None else '-':>11}" for k, _, fmt in _COLUMNS)
            backend = median.get("backend_median_ms_per_keyframe")
            print(f"{name:<20} {system:<9}{cells} {'-' if backend is None else f'{backend:.0f}':>9}")
            errors = [r["error"] for r in clip[system]["rounds"] if "error" in r]
            if errors:
                print(f"{'':<20} {'':<9} failed {len(errors)} of {len(clip[system]['rounds'])} rounds: {errors[-1]}")
        ratios = clip["ratio_zenslam_over_orbslam3"]
        cells = [f"{k.split(' ')[0]} {v:.2f}" for k, v in ratios.items() if v is not None]
        if cells:
            print(f"{'':<20} {'z/o':<9} " + ", ".join(cells))
    print("(medians over rounds; zenslam's peak RSS and PSS: the sums of its processes' peaks; BE: backend per keyframe;")
    print(f" ATE ratios only where both systems tracked at least {_MIN_TRACKED_SHARE:.0%} of the frames)")


# ---------------------------------------------------------------- main


def orbslam3_status() -> tuple[str | None, str | None]:
    """(pyorbslam3's version, why ORB-SLAM3's half cannot run): one of the two is None."""
    if importlib.util.find_spec("pyorbslam3") is None:
        return None, "pyorbslam3 is not installed (pip install -e '.[bench]'): running zenslam's half only"
    return importlib.metadata.version("pyorbslam3"), None


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="rounds over the clips, interleaved")
    parser.add_argument("--clips", nargs="+", choices=sorted(CLIPS), default=list(CLIPS))
    parser.add_argument("--data", type=Path, default=Path(os.environ.get("ZENSLAM_DATA", REPO.parent / "shared" / "data")))
    parser.add_argument("--pipelined", action="store_true", help="run zenslam --pipelined instead of --lockstep")
    parser.add_argument("--orbslam3-rate", type=float, default=1.0,
                        help="feed ORB-SLAM3 frames at this multiple of the clip's rate (0: as fast as it takes them)")  # fmt: skip
    parser.add_argument("--orbslam3-n-features", type=int, default=None,
                        help="ORB features per image for ORB-SLAM3 (default: zenslam's; ORB-SLAM's KITTI files use 2000)")  # fmt: skip
    parser.add_argument("--config", type=Path, default=None, help="run config YAML for zenslam; its ORB values go to ORB-SLAM3 too")
    parser.add_argument("--keep", type=Path, default=None, help="keep the runs, settings and logs in this folder")
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--orbslam3-child", type=Path, default=None, help=argparse.SUPPRESS)
    return parser.parse_args()


def run_rounds(report: dict, sources: dict[str, Source], inputs: dict[str, dict[str, Path]], work: Path, args) -> None:
    """Every round over the clips, the two systems in alternating order; their figures into ``report``."""
    for round_index in range(args.rounds):
        for name, source in sources.items():
            entry = report["clips"][name]
            order = ("zenslam", "orbslam3") if round_index % 2 == 0 else ("orbslam3", "zenslam")
            for system in order:
                tag = f"{name}-{system}-r{round_index}"
                if system == "zenslam":
                    mode = report["zenslam_mode"]
                    figures = run_zenslam(entry["spec"], CLIPS[name].sensor, work, mode, args.config, tag)
                elif report["orbslam3_unavailable"]:
                    continue
                else:
                    figures = run_orbslam3(entry["spec"], source, inputs[name], work, args.orbslam3_rate, tag)
                    if figures.pop("import_failed", False):
                        report["orbslam3_unavailable"] = figures["error"]
                        print(f"ORB-SLAM3 skipped: {figures['error']}")
                figures["load_1min_before"] = os.getloadavg()[0]
                entry[system]["rounds"].append(figures)
                shown = figures.get("error") or f"ATE {figures['ate_m'] or float('nan'):.4f} m, wall {figures['wall_s']:.1f} s"
                print(f"round {round_index + 1}/{args.rounds} {name} {system}: {shown}", flush=True)


def main() -> None:
    args = parse_args()
    if args.orbslam3_child is not None:
        orbslam3_child(args.orbslam3_child)
        return
    from zenslam.service.run_config import load_run_config

    config = load_run_config(args.config)
    version, unavailable = orbslam3_status()
    if unavailable:
        print(unavailable)
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    report: dict = {
        "machine": platform.platform(), "cpus": os.cpu_count(), "load_1_5_15_before": os.getloadavg(),
        "environment": environment.describe(),
        "commit": commit.stdout.strip(), "pyorbslam3": version, "orbslam3_unavailable": unavailable,
        "zenslam_mode": "pipelined" if args.pipelined else "lockstep", "orbslam3_rate": args.orbslam3_rate,
        "orbslam3_n_features": args.orbslam3_n_features or config.frontend.orb.n_features,
        "rounds": args.rounds, "clips": {},
    }  # fmt: skip
    sources = {name: open_source(CLIPS[name].resolved(args.data), CLIPS[name].sensor) for name in args.clips}
    for name, source in sources.items():
        report["clips"][name] = {"spec": CLIPS[name].resolved(args.data), "sensor": source.sensor,
                                 "frames": len(source), "zenslam": {"rounds": []}, "orbslam3": {"rounds": []}}  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="vs_orbslam3-") as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        inputs: dict[str, dict[str, Path]] = {}
        if not unavailable:
            vocabulary = export_vocabulary(work / "zenslam_vocabulary.dbow2.txt", config.frontend.vocabulary)
            for name, source in sources.items():
                inputs[name] = prepare_orbslam3_inputs(name, source, config, args.orbslam3_n_features, work, vocabulary)
        run_rounds(report, sources, inputs, work, args)
    for clip in report["clips"].values():
        summarise(clip)
    print_table(report)
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.results}")


if __name__ == "__main__":
    main()
