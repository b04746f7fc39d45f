"""Benchmark loop-closing geometry: essential-graph optimisation, the similarity RANSAC, global BA.

Synthetic, with known truth:

- ``pose_graph``: a drifting loop of N keyframes 0.5 m apart on a circle, driven a little more than
  one lap, so keyframe N-1 revisits keyframe 4. The map's poses come from relative poses with a
  yaw bias and noise (and, for Sim(3), a translation scale shrinking by a fixed fraction per
  keyframe, as monocular scale drift). Essential graph: spanning tree (i-1, i), covisibility edges
  (i-2, i), (i-3, i). Loop: the current keyframe's neighbourhood (N-4..N-1) corrected with the
  measured loop transform (truth + 1 cm / 0.1 deg noise; Sim(3) with the true scale ratio), new
  loop edges in a band between it and the loop keyframe's neighbourhood, the loop keyframe fixed.
  A *bogus* loop matches keyframe N-1 to keyframe N/2, on the far side, with a transform a
  wrong place recognition would give (0.3 m ahead, 3 deg): the correct answer is to leave the
  map's poses as they are. Figures: end error of keyframe N-1 and the mean position error
  against the truth (correct loops), the largest move of any keyframe away from the map's poses
  (bogus loops), the loop edges' final weights and the time.
  Robust variants: ``cauchy`` (starts from the corrected and the uncorrected poses, keeps the
  lower cost: the default), ``cauchy_corrected_start`` (ORB-SLAM's start only), ``gnc_tls``,
  ``gnc_gm``, ``none``.
- ``sim3_ransac``: ``find_similarity`` + ``optimize_similarity`` on 100-400 matches with 50% outliers.
- ``global_ba``: a stereo map of K keyframes along a corridor-like path with P points, each seen by
  the keyframes that see it in their image (as local mapping would have associated it), poses
  2 cm / 0.2 deg and points 3 cm off; the time of one ``run_global_ba``.

Times are process CPU (``cpu_ms``) and wall (``time_ms``) on a shared machine: compare ratios
from one run. Run: ``.venv/bin/python benchmarks/loop_geometry.py`` (writes
benchmarks/results/loop_geometry.json); ``--quick`` for smaller sizes and fewer repeats.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from zenslam.backend.essential_graph import EssentialEdge
from zenslam.backend.pose_graph import PoseGraphConfig, optimize_essential_graph
from zenslam.geometry import invert_T, make_T, so3_exp

RESULTS = Path(__file__).resolve().parent / "results" / "loop_geometry.json"


# ---- pose graph ---------------------------------------------------------------------------------
def circle_truth(n: int, step_m: float = 0.5, overlap: int = 5) -> np.ndarray:
    """(n, 4, 4) true T_world_cam on a circle (camera forward along the path, y down); keyframe n-1 revisits keyframe overlap-1."""
    per_lap = n - overlap
    radius = step_m * per_lap / (2 * np.pi)
    poses = []
    for i in range(n):
        a = 2 * np.pi * i / per_lap
        forward = np.array([-np.sin(a), np.cos(a), 0.0])
        down = np.array([0.0, 0.0, -1.0])
        R = np.column_stack([np.cross(down, forward), down, forward])
        poses.append(make_T(R, radius * np.array([np.cos(a), np.sin(a), 0.0])))
    return np.array(poses)


def drifting_loop(n: int, seed: int, yaw_bias_rad: float, scale_drift: float = 0.0, bogus_shift: int = 0):
    """A pose-graph problem: dict with truth, poses_before, corrected, edges, new_loop_edges, fixed.

    ``bogus_shift`` > 0: the loop is matched ``bogus_shift`` keyframes too far along the path, with the
    transform of the true revisit (an aliased place looks the same from the same viewpoint).
    """
    rng = np.random.default_rng(seed)
    truth = circle_truth(n)
    before = [truth[0]]
    for i in range(n - 1):
        z = invert_T(truth[i]) @ truth[i + 1]
        noise = make_T(so3_exp(rng.normal(scale=0.001, size=3) + np.array([0.0, yaw_bias_rad, 0.0])), rng.normal(scale=0.005, size=3))
        z = z @ noise
        z[:3, 3] *= (1.0 - scale_drift) ** i  # the map's units per metre shrink along the path
        before.append(before[-1] @ z)
    before = np.array(before)
    current = n - 1
    revisited = 4
    loop = revisited + bogus_shift
    noise = make_T(so3_exp(rng.normal(scale=np.radians(0.1), size=3)), rng.normal(scale=0.01, size=3))
    S_loop_cur = invert_T(truth[revisited]) @ truth[current] @ noise
    local_scale = (1.0 - scale_drift) ** (current - 1) / (1.0 - scale_drift) ** max(loop - 1, 0)
    S_loop_cur[:3, 3] *= (1.0 - scale_drift) ** max(loop - 1, 0)  # in the loop keyframe's map units
    S_loop_cur[:3, :3] *= 1.0 / local_scale  # p_loop = s R p_cur + t with s = loop units / current units
    S_world_cur = before[loop] @ S_loop_cur
    neighbourhood = list(range(current - 3, current + 1))
    corrected = {k: S_world_cur @ invert_T(before[current]) @ before[k] for k in neighbourhood}
    loop_neighbourhood = list(range(loop - 2, loop + 3))
    offset = current - loop
    new_loop_edges = [(j, i) for i in neighbourhood for j in loop_neighbourhood if abs((i - offset) - j) <= 2]
    edges = [EssentialEdge(i - 1, i, "spanning_tree") for i in range(1, n)]
    edges += [EssentialEdge(i - d, i, "covisibility") for d in (2, 3) for i in range(d, n)]
    return {
        "truth": truth, "before": before, "poses_before": {k: before[k] for k in range(n)}, "corrected": corrected,
        "edges": sorted(edges), "new_loop_edges": new_loop_edges, "fixed": {loop}, "current": current,
    }  # fmt: skip


def pose_graph_case(n, seed, yaw_bias_rad, scale_drift, bogus_shift, config) -> dict:
    problem = drifting_loop(n, seed, yaw_bias_rad, scale_drift, bogus_shift)
    with_scale = scale_drift > 0
    cpu = time.process_time()
    result = optimize_essential_graph(
        problem["poses_before"], problem["corrected"], problem["edges"], problem["new_loop_edges"],
        problem["fixed"], with_scale, config,
    )  # fmt: skip
    cpu_ms = 1e3 * (time.process_time() - cpu)
    truth, before, cur = problem["truth"], problem["before"], problem["current"]
    after = np.array([result.T_world_cam[k][:3, 3] for k in range(n)])
    weights = list(result.loop_edge_weights.values())
    return {
        "end_error_before_m": float(np.linalg.norm(before[cur, :3, 3] - truth[cur, :3, 3])),
        "end_error_after_m": float(np.linalg.norm(after[cur] - truth[cur, :3, 3])),
        "mean_error_before_m": float(np.mean(np.linalg.norm(before[:, :3, 3] - truth[:, :3, 3], axis=1))),
        "mean_error_after_m": float(np.mean(np.linalg.norm(after - truth[:, :3, 3], axis=1))),
        "max_move_from_before_m": float(np.max(np.linalg.norm(after - before[:, :3, 3], axis=1))),
        "end_scale": result.scale[cur],
        "loop_weight_min": float(min(weights)),
        "loop_weight_max": float(max(weights)),
        "accepted": 0.0 if result.stats["loop_rejected"] else 1.0,
        "time_ms": result.stats["time_ms"],
        "cpu_ms": cpu_ms,
    }


POSE_GRAPH_VARIANTS = {
    "cauchy": PoseGraphConfig(),
    "cauchy_keep_rejected": PoseGraphConfig(reject_below_weight=0.0),
    "gnc_tls": PoseGraphConfig(robust="gnc", gnc_loss="tls"),
    "gnc_tls_keep_rejected": PoseGraphConfig(robust="gnc", gnc_loss="tls", reject_below_weight=0.0),
    "gnc_gm": PoseGraphConfig(robust="gnc", gnc_loss="gm"),
    "none": PoseGraphConfig(robust="none"),
}


def bench_pose_graph(sizes, seeds, variants) -> list[dict]:
    rows = []
    for n in sizes:
        far = n // 2 - 4
        scenarios = [  # name, yaw bias (rad per keyframe), scale drift (per keyframe), bogus shift (keyframes)
            ("se3_correct", 0.0001, 0.0, 0),
            ("se3_correct_more_drift", 0.0003, 0.0, 0),
            ("se3_bogus_5m", 0.0001, 0.0, 10),
            ("se3_bogus_25m", 0.0001, 0.0, 50),
            ("se3_bogus_far", 0.0001, 0.0, far),
            ("sim3_correct", 0.0001, 0.0005, 0),
            ("sim3_bogus_25m", 0.0001, 0.0005, 50),
            ("sim3_bogus_far", 0.0001, 0.0005, far),
        ]
        for name, yaw_bias, scale_drift, shift in scenarios:
            for variant in variants:
                runs = [pose_graph_case(n, seed, yaw_bias, scale_drift, shift, POSE_GRAPH_VARIANTS[variant]) for seed in seeds]
                row = {"n_keyframes": n, "scenario": name, "variant": variant}
                row.update({key: statistics.median(r[key] for r in runs) for key in runs[0]})
                row["cpu_ms_max"] = max(r["cpu_ms"] for r in runs)
                rows.append(row)
                print(
                    f"pose graph {n:4d} kf {name:23s} {variant:21s} accepted {row['accepted']:.1f} end {row['end_error_before_m']:6.2f} -> "
                    f"{row['end_error_after_m']:6.2f} m, mean {row['mean_error_before_m']:5.2f} -> {row['mean_error_after_m']:5.2f} m, "
                    f"moved <= {row['max_move_from_before_m']:7.2f} m, loop w [{row['loop_weight_min']:.2f}, "
                    f"{row['loop_weight_max']:.2f}], {row['cpu_ms']:5.0f} ms cpu (max {row['cpu_ms_max']:.0f})",
                    flush=True,
                )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller sizes, one seed")
    parser.add_argument("--only", choices=["pose_graph", "sim3", "global_ba"], action="append", help="run only these parts")
    args = parser.parse_args()
    parts = args.only or ["pose_graph", "sim3", "global_ba"]
    out: dict = {"machine": platform.processor() or platform.machine(), "quick": args.quick}
    if "pose_graph" in parts:
        sizes, seeds = ((200,), (0,)) if args.quick else ((500,), (0, 1, 2))
        out["pose_graph"] = bench_pose_graph(sizes, seeds, list(POSE_GRAPH_VARIANTS))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=1))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
