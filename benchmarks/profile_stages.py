"""Profile the frontend's step and the backend's keyframe processing, in one process, by function and module.

Runs ``FrontendPipeline`` over a clip with local mapping (``LocalMapper``) answering each keyframe
before the next frame, as lockstep does, and profiles the two apart with cProfile: the frontend's
``step`` calls and the map updates it applies, and the backend's ``process`` calls. Each is
summarised by module (self time summed over the module's functions) and by function (self and
cumulative time), with CPU time per frame and per keyframe, to show where compiled kernels would
pay. cProfile's own overhead inflates many small Python calls more than a few large numpy or
OpenCV ones, so the shares are a guide, not timings: ``frontend_tracking.py`` and
``backend_stages.py`` time the stages without it.

Run: ``.venv/bin/python benchmarks/profile_stages.py [--data ../shared/data] [--corridor-frames N]``
(writes benchmarks/results/profile_stages.json).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import platform
import pstats
import subprocess
import time
from collections import defaultdict
from pathlib import Path

from zenslam.frontend.pipeline import FrontendConfig, FrontendPipeline

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "profile_stages.json"
TOP = 25  # functions listed per stage


def _local_mapper():
    from zenslam.backend.config import BackendConfig
    from zenslam.backend.local_mapping import LocalMapper, bundle_adjuster, new_backend_map

    config = BackendConfig()
    return LocalMapper(new_backend_map(config.local_mapping), config.local_mapping, bundle_adjuster(config.local_ba))


def _warm_up_kernels() -> None:
    """Compile (or load from the cache) every kernel first, as the stages do at start, so that the
    profiles show the per-frame work rather than numba's compiler."""
    from zenslam.backend.config import BackendConfig
    from zenslam.backend.kernel_warm_up import warm_up_kernels as warm_up_backend
    from zenslam.frontend.kernel_warm_up import warm_up_kernels as warm_up_frontend

    warm_up_frontend()
    warm_up_backend(BackendConfig())


def profile_run(source, max_frames: int | None) -> dict:
    """Track ``source``'s frames (loaded beforehand) with both profilers; their summaries and counts."""
    from zenslam.frontend.node import keyframe_message
    from zenslam.schemas import codec

    frames = list(source)[:max_frames]
    pipeline = FrontendPipeline(FrontendConfig(), source.calibration, source.sensor)
    mapper = _local_mapper()
    _warm_up_kernels()
    frontend, backend = cProfile.Profile(time.process_time), cProfile.Profile(time.process_time)
    n_keyframes = 0
    for frame in frames:
        frontend.enable()
        out = pipeline.step(frame.index, frame.stamp_ns, frame.left, right=frame.right, depth_m=frame.depth_m)
        frontend.disable()
        for keyframe in out.keyframes_made:
            message = codec.decode_keyframe(codec.encode_keyframe(keyframe_message(keyframe, source.calibration, source.sensor)))
            backend.enable()
            update = mapper.process(message)
            backend.disable()
            frontend.enable()
            pipeline.apply_map_update(update)
            frontend.disable()
            n_keyframes += 1
    return {
        "frames": len(frames),
        "keyframes": n_keyframes,
        "image_size": [source.calibration.width, source.calibration.height],
        "frontend": summarise(frontend, len(frames)),
        "backend": summarise(backend, max(n_keyframes, 1)),
    }


def summarise(profile: cProfile.Profile, per: int) -> dict:
    """Self time by module and by function, in CPU milliseconds per ``per`` (frames or keyframes)."""
    stats = pstats.Stats(profile)
    total_s = stats.total_tt
    by_module: dict[str, float] = defaultdict(float)
    functions = []
    for (filename, line, name), (_, calls, self_s, cumulative_s, _) in stats.stats.items():
        module = _module_of(filename)
        by_module[module] += self_s
        functions.append((self_s, cumulative_s, calls, f"{module}:{line}({name})"))
    functions.sort(reverse=True)
    return {
        "cpu_ms_per": 1000 * total_s / per,
        "modules": [
            {"module": m, "self_ms_per": 1000 * s / per, "share": s / total_s}
            for m, s in sorted(by_module.items(), key=lambda kv: -kv[1])[:TOP]
        ],
        "functions": [
            {"function": f, "self_ms_per": 1000 * s / per, "cumulative_ms_per": 1000 * c / per, "calls_per": n / per}
            for s, c, n, f in functions[:TOP]
        ],
    }


def _module_of(filename: str) -> str:
    """``zenslam/frontend/x.py`` for the project's files, the package for others, ``~`` for built-ins."""
    path = Path(filename)
    if "zenslam" in path.parts:
        return "/".join(path.parts[path.parts.index("zenslam"):])
    if "site-packages" in path.parts:
        return path.parts[path.parts.index("site-packages") + 1]
    return filename  # "~" (C functions: numpy, OpenCV and built-in calls) and the standard library


def print_stage(name: str, stage: dict, unit: str) -> None:
    print(f"  {name}: {stage['cpu_ms_per']:.1f} ms CPU per {unit} (profiled)")
    for row in stage["modules"][:12]:
        print(f"    {row['share'] * 100:5.1f}%  {row['self_ms_per']:7.2f} ms  {row['module']}")
    print("    functions by self time:")
    for row in stage["functions"][:12]:
        print(f"      {row['self_ms_per']:7.2f} ms self {row['cumulative_ms_per']:7.2f} cum {row['calls_per']:8.1f} calls  {row['function']}")


def sources(data: Path, corridor_frames: int):
    from zenslam.service.sources.kitti import KittiSource
    from zenslam.service.sources.synthetic import SyntheticSource, scene_config

    yield "kitti_06_clip", KittiSource(data / "kitti_odometry" / "sequences" / "06"), None
    if corridor_frames > 0:
        yield "synthetic_corridor_stereo", SyntheticSource(scene_config("corridor", sensor="stereo")), corridor_frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data", help="benchmark clips root")
    parser.add_argument("--corridor-frames", type=int, default=200, help="frames of synthetic:corridor to profile")
    args = parser.parse_args()
    runs = {}
    for name, source, max_frames in sources(args.data, args.corridor_frames):
        load_before = os.getloadavg()[0]
        runs[name] = {**profile_run(source, max_frames), "load_average_before": load_before}
        r = runs[name]
        print(f"{name} ({r['frames']} frames, {r['keyframes']} keyframes, {r['image_size'][0]}x{r['image_size'][1]}; load {load_before:.1f})")
        print_stage("frontend", r["frontend"], "frame")
        print_stage("backend", r["backend"], "keyframe")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout.strip()
    report = {"commit": commit, "machine": platform.platform(), "python": platform.python_version(), "cpu_count": os.cpu_count(), "runs": runs}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
