"""Benchmark the frontend's map cache: its size along a run with and without eviction, and the ATE of both.

The frontend and the backend run in one process in lockstep order without the bus (as in
``backend_quality.py``): each keyframe goes through the bus codec to ``BackendNode.step`` and its
``MapUpdate`` (through the codec too) is applied before the next frame. The run is made twice on
the synthetic figure-eight (1,201 frames, two laps): with ``LocalMapConfig(evict=False)`` (the
cache grows into a full copy of the map) and with the default eviction. Every 100 frames (and at
the last) it records the cache's keyframes, point rows (and the valid ones among them) and bytes
(``LocalMap.nbytes``: the point and observation arrays at their capacity, the keyframes' arrays,
the indexes); at the end the ATE (evo, SE(3)) of the per-frame poses and of the backend's keyframes,
and the eviction passes with their time.

Run: ``.venv/bin/python benchmarks/frontend_cache.py [--scene figure_eight] [--sensor stereo]
[--max-frames N] [--every 100]`` (writes benchmarks/results/frontend_cache.json). Each run takes
~10 min on the shared 2-core machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
import platform
import time
from pathlib import Path

from backend_quality import ate_of

from zenslam.backend.config import BackendConfig
from zenslam.backend.node import BackendNode
from zenslam.frontend.config import FrontendConfig
from zenslam.frontend.node import keyframe_message
from zenslam.frontend.pipeline import FrontendPipeline
from zenslam.schemas import codec
from zenslam.service.sources.synthetic import SyntheticSource, scene_config

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "frontend_cache.json"


def frontend_config(evict: bool) -> FrontendConfig:
    config = FrontendConfig()
    local_map = dataclasses.replace(config.tracking.local_map, evict=evict)
    return dataclasses.replace(config, tracking=dataclasses.replace(config.tracking, local_map=local_map))


def run_once(scene: str, sensor: str, evict: bool, max_frames: int | None, every: int) -> dict:
    """Track the scene with the backend in lockstep order; the cache's size every ``every`` frames."""
    source = SyntheticSource(scene_config(scene, sensor=sensor))
    calibration = source.calibration
    pipeline = FrontendPipeline(frontend_config(evict), calibration, sensor)
    backend = BackendNode.from_config(BackendConfig())
    eviction = pipeline.tracker.eviction
    pass_ms: list[float] = []
    evict_once = eviction.maybe_evict

    def timed_evict(*args, **kwargs):
        start = time.perf_counter()
        done = evict_once(*args, **kwargs)
        if done is not None:
            pass_ms.append((time.perf_counter() - start) * 1e3)
        return done

    eviction.maybe_evict = timed_evict
    stamps, poses, states, samples = [], [], [], []
    frames = list(itertools.islice(source, max_frames)) if max_frames else source
    start = time.perf_counter()
    last_index = (max_frames or scene_config(scene, sensor=sensor).frame_count()) - 1
    for frame in frames:
        out = pipeline.step(frame.index, frame.stamp_ns, frame.left, right=frame.right, depth_m=frame.depth_m)
        states.append(out.state)
        if out.T_world_cam is not None:
            stamps.append(out.stamp_ns)
            poses.append(out.T_world_cam)
        if out.keyframe is not None:
            message = codec.decode_keyframe(codec.encode_keyframe(keyframe_message(out.keyframe, calibration, sensor)))
            for update in backend.step(message).updates:  # the answer, then any loop correction
                pipeline.apply_map_update(codec.decode_map_update(codec.encode_map_update(update)))
        if frame.index % every == 0 or frame.index == last_index:
            lm = pipeline.tracker.map
            samples.append({"frame": frame.index, "keyframes_made": lm.n_keyframes, "keyframes": lm.n_cached_keyframes,
                            "points": lm.n_points, "valid_points": lm.n_valid_points, "bytes": lm.nbytes()})  # fmt: skip
    ground_truth = source.ground_truth()
    kfs = list(backend.map.keyframes.values())
    return {
        "evict": evict,
        "frames": len(states),
        "wall_s": time.perf_counter() - start,
        "states": {s: states.count(s) for s in ("ok", "lost", "initializing")},
        "samples": samples,
        "ate_per_frame": ate_of(stamps, poses, ground_truth),
        "ate_keyframes": ate_of([kf.stamp_ns for kf in kfs], [kf.T_world_cam for kf in kfs], ground_truth),
        "eviction_passes": len(pass_ms),
        "eviction_pass_ms": {"mean": sum(pass_ms) / len(pass_ms), "max": max(pass_ms)} if pass_ms else None,
    }


def print_run(r: dict) -> None:
    a, k = r["ate_per_frame"], r["ate_keyframes"]
    print(f"evict={r['evict']}: ATE per frame {a['rmse_m'] * 100:.2f} cm (max {a['max_m'] * 100:.2f}), keyframes "
          f"{k['rmse_m'] * 100:.2f} cm; states {r['states']}; wall {r['wall_s']:.0f} s")  # fmt: skip
    if r["eviction_passes"]:
        t = r["eviction_pass_ms"]
        print(f"  {r['eviction_passes']} eviction passes, mean {t['mean']:.1f} ms, max {t['max']:.1f} ms")
    print(f"  {'frame':>6} {'kf made':>8} {'kf cached':>10} {'points':>8} {'valid':>7} {'MB':>7}")
    for s in r["samples"]:
        print(f"  {s['frame']:>6} {s['keyframes_made']:>8} {s['keyframes']:>10} {s['points']:>8} {s['valid_points']:>7} "
              f"{s['bytes'] / 1e6:>7.2f}")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="figure_eight", help="synthetic scene (loop, figure_eight)")
    parser.add_argument("--sensor", default="stereo", choices=("stereo", "rgbd"))
    parser.add_argument("--max-frames", type=int, default=None, help="use only the first N frames")
    parser.add_argument("--every", type=int, default=100, help="sample the cache every N frames")
    args = parser.parse_args()
    runs = []
    for evict in (False, True):
        runs.append(run_once(args.scene, args.sensor, evict, args.max_frames, args.every))
        print_run(runs[-1])
    report = {"machine": platform.platform(), "python": platform.python_version(), "cpu_count": os.cpu_count(),
              "scene": f"synthetic:{args.scene}/{args.sensor}", "config": "FrontendConfig(), BackendConfig() defaults; "
              "before: tracking.local_map.evict=False", "load_after": os.getloadavg(), "runs": runs}  # fmt: skip
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
