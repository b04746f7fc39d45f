"""Loop closing check by check: runs in process (lockstep), and every verified loop's outcome, correction and error.

For each source (a source spec: ``synthetic:loop/mono,seed=3``, ``kitti:<sequence folder>``, ...)
and each backend configuration (``--config`` YAML files with a ``backend`` section; none: the
defaults), one lockstep run without the bus, as ``backend_quality.py`` makes them: frames tracked
by ``FrontendPipeline``, keyframes through the bus codec to ``BackendNode.step``, map updates back.
Printed and written (benchmarks/results/loop_checks.json):
- ATE as tracked and of the keyframes at the end (SE(3), and Sim(3): monocular maps have a scale of
  their own), keyframes made, wall time;
- each loop that passed verification (``backend/loop`` messages with inliers): keyframe -> loop
  keyframe, A accepted or R refused (with the reason: drift budget, pose graph), the correction it
  asked for as a share of the keyframes' path from the loop keyframe (what ``drift_budget``
  compares), and its error against the ground truth (translation, rotation; monocular: in metres
  through the Sim(3) alignment's scale).

So a change to loop closing reads as "which loops it takes, how right they were, what the map
became". Run: ``.venv/bin/python benchmarks/loop_checks.py --source synthetic:loop/mono,seed=4
[--source ...] [--config a.yaml --config b.yaml] [--output FILE]``; each run of a room scene takes
minutes.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from backend_quality import ate_of

from zenslam.backend.config import BackendConfig
from zenslam.backend.node import BackendNode
from zenslam.backend.pose_graph import correction_and_path
from zenslam.config import from_mapping, load_yaml
from zenslam.frontend.node import keyframe_message
from zenslam.frontend.pipeline import FrontendConfig, FrontendPipeline
from zenslam.runtime import environment
from zenslam.schemas import codec
from zenslam.service.evaluation.loop_acceptance import loop_error
from zenslam.service.sources import open_source

RESULTS = Path(__file__).resolve().parent / "results" / "loop_checks.json"


def corrected_pose(loop: codec.LoopMessage) -> np.ndarray:
    """The current keyframe's pose (4x4, camera -> world; a similarity for Sim(3)) where the loop puts
    it: the loop keyframe's pose composed with the inverse of ``T_cur_loop`` at ``scale``."""
    S_cur_loop = np.array(loop.T_cur_loop, dtype=float)
    S_cur_loop[:3, :3] *= loop.scale
    return np.asarray(loop.T_world_loop, dtype=float) @ np.linalg.inv(S_cur_loop)


def run(spec: str, backend_config: BackendConfig) -> dict:
    """One lockstep run of ``spec``: ATEs, keyframes, and each verified loop check."""
    source = open_source(spec)
    ground_truth = source.ground_truth()
    pipeline = FrontendPipeline(FrontendConfig(), source.calibration, source.sensor)
    backend = BackendNode.from_config(backend_config)
    stamps, poses, checks = [], [], []
    n_keyframes = 0
    start = time.perf_counter()
    try:
        for frame in source:
            out = pipeline.step(frame.index, frame.stamp_ns, frame.left, right=frame.right, depth_m=frame.depth_m)
            if out.T_world_cam is not None:
                stamps.append(out.stamp_ns)
                poses.append(out.T_world_cam)
            for keyframe in out.keyframes_made:
                n_keyframes += 1
                before = {k: kf.T_world_cam.copy() for k, kf in backend.map.keyframes.items()}
                message = codec.encode_keyframe(keyframe_message(keyframe, source.calibration, source.sensor))
                step = backend.step(codec.decode_keyframe(message))
                checks.extend(_check(loop, before) for loop in step.loops if loop.inliers > 0)
                for update in step.updates:
                    pipeline.apply_map_update(codec.decode_map_update(codec.encode_map_update(update)))
        keyframes = sorted(backend.map.keyframes.values(), key=lambda kf: kf.stamp_ns)
    finally:
        backend.close()
    tracked = ate_of(stamps, poses, ground_truth)
    at_end = ate_of([kf.stamp_ns for kf in keyframes], [kf.T_world_cam for kf in keyframes], ground_truth)
    metres_per_unit = at_end["sim3_scale"] if source.sensor == "mono" else 1.0
    for check, loop in checks:
        error = loop_error(loop, ground_truth, metres_per_unit)
        check["error_m"], check["error_deg"] = (round(error[0], 4), round(error[1], 3)) if error else (None, None)
    return {
        "source": spec, "sensor": source.sensor, "wall_s": round(time.perf_counter() - start, 1),
        "keyframes_made": n_keyframes, "keyframes_kept": len(keyframes),
        "ate_cm": round(100 * tracked["rmse_m"], 3), "sim3_ate_cm": round(100 * tracked["sim3_rmse_m"], 3),
        "keyframes_ate_cm": round(100 * at_end["rmse_m"], 3), "keyframes_sim3_ate_cm": round(100 * at_end["sim3_rmse_m"], 3),
        "checks": [check for check, _ in checks],
    }  # fmt: skip


def _check(loop: codec.LoopMessage, poses_before: dict[int, np.ndarray]) -> tuple[dict, codec.LoopMessage]:
    """One verified loop's figures; ``poses_before``: the map's keyframes before this keyframe's step
    (the current keyframe, inserted by the step, is where local mapping left it: ``T_world_cur_before``)."""
    poses = poses_before | {loop.keyframe_id: loop.T_world_cur_before}
    moved, path = correction_and_path(poses, loop.loop_keyframe_id, loop.keyframe_id, corrected_pose(loop))
    check = {
        "keyframe_id": int(loop.keyframe_id), "loop_keyframe_id": int(loop.loop_keyframe_id),
        "outcome": "A" if loop.accepted else "R", "reason": loop.reason, "inliers": int(loop.inliers),
        "moved": round(moved, 4), "share_of_path": round(moved / max(path, 1e-12), 5),
    }  # fmt: skip
    return check, loop


def _print(name: str, r: dict) -> None:
    print(
        f"{r['source']} [{name}]: ATE {r['ate_cm']:.3f} cm (Sim(3) {r['sim3_ate_cm']:.3f}), keyframes {r['keyframes_ate_cm']:.3f} "
        f"(Sim(3) {r['keyframes_sim3_ate_cm']:.3f}); {r['keyframes_made']} keyframes made, {r['keyframes_kept']} kept; {r['wall_s']:.0f} s",
        flush=True,
    )
    for c in r["checks"]:
        error = "" if c["error_m"] is None else f", {100 * c['error_m']:.2f} cm / {c['error_deg']:.2f} deg off the truth"
        why = f" ({c['reason']})" if c["reason"] else ""
        print(f"  {c['keyframe_id']} -> {c['loop_keyframe_id']}: {c['outcome']}{why}, {c['inliers']} inliers, "
              f"{100 * c['share_of_path']:.2f}% of the path{error}", flush=True)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", action="append", required=True, help="source spec (repeatable)")
    parser.add_argument("--config", action="append", type=Path, default=[], help="YAML with a backend section (repeatable; none: defaults)")
    parser.add_argument("--output", type=Path, default=RESULTS, help=f"JSON written (default {RESULTS})")
    args = parser.parse_args()
    configs = {"defaults": BackendConfig()} if not args.config else {
        str(path): from_mapping(BackendConfig, load_yaml(path).get("backend"), "backend") for path in args.config
    }  # fmt: skip
    rows = []
    for spec in args.source:
        for name, config in configs.items():
            row = run(spec, config) | {"config": name}
            _print(name, row)
            rows.append(row)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({"environment": environment.describe(), "runs": rows}, indent=1))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
