"""Benchmark loop-closing geometry: essential-graph optimisation, the similarity RANSAC, global BA.

Synthetic, with known truth:

- ``pose_graph``: a drifting loop of N keyframes 0.5 m apart on a circle, driven a little more than
  one lap, so keyframe N-1 revisits keyframe 4. The map's poses come from relative poses with a
  yaw bias and noise (and, for Sim(3), a translation scale shrinking by a fixed fraction per
  keyframe, as monocular scale drift). Essential graph: spanning tree (i-1, i), covisibility edges
  (i-2, i), (i-3, i). Loop: the current keyframe's neighbourhood (N-4..N-1) corrected with the
  measured loop transform (truth + 1 cm / 0.1 deg noise; Sim(3) with the true scale ratio), new
  loop edges in a band between it and the loop keyframe's neighbourhood, the loop keyframe fixed.
  A *bogus* loop matches keyframe N-1 to a keyframe 5 m, 25 m or half a lap further along the
  path, with the transform of the true revisit (an aliased place seen from the same viewpoint):
  the correct answer is to leave the map's poses as they are. Figures: whether the loop was
  accepted, end error of keyframe N-1 and the mean position error against the truth, the largest
  move of any keyframe away from the map's poses, the loop edges' final weights and the time.
  Variants (loop closing's settings: the pose graph's and the drift budgets): ``default`` (what
  zenslam ships), ``cauchy`` (Cauchy on loop edges, LM from the corrected poses, a loop whose edges
  all end below weight 0.5 rejected; every edge at full information, no budget),
  ``cauchy_keep_rejected`` (the same without the rejection rule), ``cauchy_shared`` (covisibility
  edges sharing their information, SE(3) and Sim(3)), ``cauchy_budget5`` / ``cauchy_shared_budget5``
  / ``cauchy_shared_budget10`` (a drift budget of 5% or 10% of the path applied first, here to SE(3)
  and Sim(3) cases alike), ``gnc_tls`` / ``gnc_tls_keep_rejected`` (gtsam's GNC with TLS, with and
  without the rule), ``gnc_gm``, ``none``.
  Each case reports its correction as a fraction of the path (``correction_of_path``).
- ``sim3_ransac``: ``find_similarity`` + ``optimize_similarity`` on 100-400 matches with 50% outliers.
- ``global_ba``: a stereo BackendMap of K keyframes 0.4 m apart along a curving corridor with P
  points on its walls, floor and ceiling, each observed by every keyframe it projects into within
  10 m (0.5 px noise), poses 2 cm / 0.2 deg and points 3 cm off; the CPU time to build the
  problem, to run ``run_global_ba`` and to apply the result, and the error before and after
  (the optimum of noisy observations drifts from the truth along the path: the pose error after
  is that optimum's, the whitened error shows convergence). Variants: the default schedule,
  ORB-SLAM's (10 plain iterations, no Huber pass), and COLAMD ordering.

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
from zenslam.backend.global_ba import GlobalBAConfig, apply_global_ba, global_ba_problem, run_global_ba
from zenslam.backend.local_mapping import BAWindowConfig
from zenslam.backend.loop_closing_config import LoopClosingConfig
from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.backend.pose_graph import PoseGraphConfig, correction_and_path, optimize_essential_graph
from zenslam.backend.similarity import (
    SimilarityMatches,
    SimilarityOptimizationConfig,
    SimilarityRansacConfig,
    find_similarity,
    optimize_similarity,
)
from zenslam.camera import PinholeCalibration
from zenslam.geometry import invert_T, make_T, so3_exp, transform_points
from zenslam.runtime import environment

RESULTS = Path(__file__).resolve().parent / "results" / "loop_geometry.json"
ROOM = PinholeCalibration(460.0, 460.0, 320.0, 240.0, 640, 480, baseline_m=0.10)


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


def pose_graph_case(n, seed, yaw_bias_rad, scale_drift, bogus_shift, variant: LoopClosingConfig) -> dict:
    """One problem through the pose graph (``variant.pose_graph``); with a drift budget (loop closing's
    ``drift_budget``, or ``drift_budget_monocular`` for Sim(3)) a loop moving the current keyframe by
    more than that fraction of the path is rejected first."""
    config = variant.pose_graph
    problem = drifting_loop(n, seed, yaw_bias_rad, scale_drift, bogus_shift)
    with_scale = scale_drift > 0
    drift_budget = variant.drift_budget_monocular if with_scale else variant.drift_budget
    truth, before, cur = problem["truth"], problem["before"], problem["current"]
    (loop,) = problem["fixed"]
    moved, path = correction_and_path(problem["poses_before"], loop, cur, problem["corrected"][cur])
    cpu = time.process_time()
    result = optimize_essential_graph(
        problem["poses_before"], problem["corrected"], problem["edges"], problem["new_loop_edges"],
        problem["fixed"], with_scale, config,
    )  # fmt: skip
    cpu_ms = 1e3 * (time.process_time() - cpu)
    # Refused by the budget: loop closing would not run the pose graph (its time is still reported) and
    # the poses stay as they were.
    if drift_budget is not None and moved > drift_budget * path:
        result = dataclasses.replace(
            result, T_world_cam={k: problem["poses_before"][k] for k in range(n)}, stats={**result.stats, "loop_rejected": True}
        )
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
        "correction_of_path": moved / path,
        "time_ms": result.stats["time_ms"],
        "cpu_ms": cpu_ms,
    }


_FULL = {"covisibility_information": "full", "covisibility_information_monocular": "full"}
_SHARED = {"covisibility_information": "shared", "covisibility_information_monocular": "shared"}


def _variant(budget: float | None = None, budget_monocular: float | None = None, **pose_graph) -> LoopClosingConfig:
    """Loop closing's settings with these pose-graph settings and drift budgets (SE(3), Sim(3))."""
    return LoopClosingConfig(pose_graph=PoseGraphConfig(**pose_graph), drift_budget=budget, drift_budget_monocular=budget_monocular)


POSE_GRAPH_VARIANTS = {  # name -> loop closing's settings: the pose graph's and the drift budgets
    "default": LoopClosingConfig(),  # what zenslam ships
    "cauchy": _variant(**_FULL),
    "cauchy_k10": _variant(cauchy_k=10.0, **_FULL),
    "cauchy_keep_rejected": _variant(reject_below_weight=0.0, **_FULL),
    "cauchy_shared": _variant(**_SHARED),
    "cauchy_shared_budget5": _variant(0.05, 0.05, **_SHARED),
    "cauchy_budget5": _variant(0.05, 0.05, **_FULL),
    "cauchy_shared_budget10": _variant(0.10, 0.10, **_SHARED),
    "gnc_tls": _variant(robust="gnc", gnc_loss="tls", **_FULL),
    "gnc_tls_keep_rejected": _variant(robust="gnc", gnc_loss="tls", reject_below_weight=0.0, **_FULL),
    "gnc_gm": _variant(robust="gnc", gnc_loss="gm", **_FULL),
    "none": _variant(robust="none", **_FULL),
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
                    f"pose graph {n:4d} kf {name:23s} {variant:22s} accepted {row['accepted']:.1f} end {row['end_error_before_m']:6.2f} -> "
                    f"{row['end_error_after_m']:6.2f} m, mean {row['mean_error_before_m']:5.2f} -> {row['mean_error_after_m']:5.2f} m, "
                    f"moved <= {row['max_move_from_before_m']:7.2f} m, correction {100 * row['correction_of_path']:5.1f}% of path, loop w [{row['loop_weight_min']:.2f}, "
                    f"{row['loop_weight_max']:.2f}], {row['cpu_ms']:5.0f} ms cpu (max {row['cpu_ms_max']:.0f})",
                    flush=True,
                )
    return rows


# ---- similarity RANSAC -----------------------------------------------------------------------
def two_keyframes(seed: int, n: int, scale: float, outlier_fraction: float):
    """Matches between two keyframes 0.8 m and 15 deg apart seeing points 2-8 m ahead (1 px x level
    noise, 1 cm depth noise); keyframe 2's map ``scale`` times smaller; wrong associations swapped in."""
    rng = np.random.default_rng(seed)
    T_w1 = make_T(so3_exp([0.02, 0.1, -0.01]), [0.3, -0.1, 0.2])
    T_w2 = make_T(so3_exp([-0.05, 0.35, 0.04]), [1.1, 0.05, -0.4])
    z = rng.uniform(2.0, 8.0, 3 * n)
    uv = np.column_stack([rng.uniform(60, 580, 3 * n), rng.uniform(60, 420, 3 * n)])
    p1 = np.column_stack([(uv[:, 0] - ROOM.cx) * z / ROOM.fx, (uv[:, 1] - ROOM.cy) * z / ROOM.fy, z])
    p2 = (np.c_[p1, np.ones(len(p1))] @ (invert_T(T_w2) @ T_w1).T)[:, :3]
    keep = np.flatnonzero(p2[:, 2] > 0.5)[:n]
    p1, p2 = p1[keep], p2[keep]
    sigma2 = 1.2 ** (2 * rng.integers(0, 4, (2, n)))
    project = lambda p: np.column_stack([ROOM.fx * p[:, 0] / p[:, 2] + ROOM.cx, ROOM.fy * p[:, 1] / p[:, 2] + ROOM.cy])  # noqa: E731
    px1 = project(p1) + rng.normal(size=(n, 2)) * np.sqrt(sigma2[0])[:, None]
    px2 = project(p2) + rng.normal(size=(n, 2)) * np.sqrt(sigma2[1])[:, None]
    p1 = p1 * (1 + 0.01 * rng.normal(size=(n, 1)) / p1[:, 2:3])
    p2 = p2 * (1 + 0.01 * rng.normal(size=(n, 1)) / p2[:, 2:3]) / scale
    bad = rng.permutation(n)[: int(outlier_fraction * n)]
    swap = rng.permutation(bad)
    p2[bad], px2[bad] = p2[swap], px2[swap]
    T_12 = invert_T(T_w1) @ T_w2
    return SimilarityMatches(p1, p2, px1, px2, sigma2[0], sigma2[1], ROOM, ROOM), T_12


def bench_sim3(sizes, seeds) -> list[dict]:
    rows = []
    for n in sizes:
        for with_scale in (False, True):
            times, opt_times, trans_err, iters, inliers = [], [], [], [], []
            for seed in seeds:
                matches, T_true = two_keyframes(seed, n, 0.7 if with_scale else 1.0, 0.5)
                t = time.process_time()
                est = find_similarity(matches, with_scale, SimilarityRansacConfig(), np.random.default_rng(seed))
                times.append(1e3 * (time.process_time() - t))
                if est is None:
                    continue
                t = time.process_time()
                opt = optimize_similarity(matches, est.T_12, est.scale, with_scale, SimilarityOptimizationConfig())
                opt_times.append(1e3 * (time.process_time() - t))
                final = opt if opt is not None else est
                trans_err.append(float(np.linalg.norm(final.T_12[:3, 3] - T_true[:3, 3])))
                iters.append(est.iterations)
                inliers.append(final.n_inliers / n)
            row = {
                "n_matches": n, "with_scale": with_scale, "outlier_fraction": 0.5, "found": len(iters) / len(seeds),
                "ransac_cpu_ms": statistics.median(times), "ransac_cpu_ms_max": max(times),
                "optimize_cpu_ms": statistics.median(opt_times), "hypotheses": statistics.median(iters),
                "translation_error_m": statistics.median(trans_err), "inlier_fraction": statistics.median(inliers),
            }  # fmt: skip
            rows.append(row)
            print(
                f"sim3 {'Sim(3)' if with_scale else 'SE(3) '} {n:4d} matches, 50% outliers: found {row['found']:.2f}, "
                f"RANSAC {row['ransac_cpu_ms']:.1f} ms (max {row['ransac_cpu_ms_max']:.1f}, {row['hypotheses']:.0f} hypotheses), "
                f"refinement {row['optimize_cpu_ms']:.1f} ms, translation error {100 * row['translation_error_m']:.2f} cm, "
                f"inliers {row['inlier_fraction']:.2f}",
                flush=True,
            )
    return rows


# ---- global BA --------------------------------------------------------------------------------
def corridor_map(n_keyframes: int, n_points: int, seed: int):
    """A stereo BackendMap along a gently curving corridor (keyframes 0.4 m apart, points on walls,
    floor and ceiling up to 8 m ahead seen where they project), poses 2 cm / 0.2 deg and points
    3 cm off; returns the map and the true poses and points."""
    rng = np.random.default_rng(seed)
    step, curve = 0.4, 0.004  # m, rad of yaw per keyframe
    poses, heading, position = [], 0.0, np.zeros(3)
    for _ in range(n_keyframes):
        forward = np.array([np.sin(heading), 0.0, np.cos(heading)])
        R = np.column_stack([np.cross([0.0, 1.0, 0.0], forward), [0.0, 1.0, 0.0], forward])
        poses.append(make_T(R, position.copy()))
        position, heading = position + step * forward, heading + curve
    # points: around random keyframes, on a wall/floor/ceiling 1.5 m from the path, 2-8 m ahead
    anchor = rng.integers(0, n_keyframes, n_points)
    ahead = rng.uniform(2.0, 8.0, n_points)
    side = rng.choice([0, 1, 2, 3], n_points)
    lateral = rng.uniform(-1.5, 1.5, n_points)
    local = np.column_stack([
        np.where(side == 0, -1.5, np.where(side == 1, 1.5, lateral)),
        np.where(side == 2, -1.2, np.where(side == 3, 1.2, 1.2 * lateral / 1.5)),
        ahead,
    ])  # fmt: skip
    points = np.array([transform_points(poses[a], local[i : i + 1])[0] for i, a in enumerate(anchor)])
    bmap = BackendMap()
    for i in range(n_points):
        bmap.add_point(i, points[i] + rng.normal(scale=0.03 / np.sqrt(3), size=3), 0)
    for k, T in enumerate(poses):
        p_cam = transform_points(invert_T(T), points)
        z = np.where(p_cam[:, 2] > 1e-6, p_cam[:, 2], 1e-6)
        u, v = ROOM.fx * p_cam[:, 0] / z + ROOM.cx, ROOM.fy * p_cam[:, 1] / z + ROOM.cy
        seen = np.flatnonzero((p_cam[:, 2] > 0.5) & (p_cam[:, 2] < 10.0) & (u >= 0) & (u < ROOM.width) & (v >= 0) & (v < ROOM.height))
        m = len(seen)
        px = np.column_stack([u[seen], v[seen]]) + rng.normal(scale=0.5, size=(m, 2))
        T_init = T if k == 0 else T @ make_T(so3_exp(rng.normal(scale=np.radians(0.2) / np.sqrt(3), size=3)), rng.normal(scale=0.02 / np.sqrt(3), size=3))
        bmap.add_keyframe(BackendKeyframe(
            id=k, stamp_ns=k, T_world_cam=T_init, calibration=ROOM, sensor="stereo", keypoints_px=px,
            levels=np.zeros(m, np.int64), angles_deg=np.zeros(m), right_u=px[:, 0] - ROOM.bf / z[seen] + rng.normal(scale=0.5, size=m),
            depth_m=z[seen].copy(), descriptors=np.zeros((m, 32), np.uint8), scale_factors=1.2 ** np.arange(8),
            map_point_ids=seen.astype(np.int64),
        ))  # fmt: skip
    bmap.remove_weak_points(list(bmap.points), 2)
    bmap.take_changes()
    return bmap, np.array(poses), points


GLOBAL_BA_VARIANTS = {
    "default": GlobalBAConfig(),
    "batch_lm": GlobalBAConfig(solver="batch_lm"),
    "schur_lm": GlobalBAConfig(solver="schur_lm"),
    "orbslam_schedule": GlobalBAConfig(robust_iterations=0, iterations=10),
    "colamd": GlobalBAConfig(ordering="colamd"),
}


def bench_global_ba(sizes, variants) -> list[dict]:
    rows = []
    for n_keyframes, n_points in sizes:
        for variant in variants:
            bmap, poses, points = corridor_map(n_keyframes, n_points, seed=0)
            error_before = float(np.median([np.linalg.norm(bmap.keyframes[k].T_world_cam[:3, 3] - poses[k][:3, 3]) for k in bmap.keyframes]))
            t = time.process_time()
            problem = global_ba_problem(bmap, BAWindowConfig())
            build_ms = 1e3 * (time.process_time() - t)
            t, wall = time.process_time(), time.perf_counter()
            result = run_global_ba(problem, GLOBAL_BA_VARIANTS[variant])
            run_ms, run_wall_ms = 1e3 * (time.process_time() - t), 1e3 * (time.perf_counter() - wall)
            t = time.process_time()
            apply_global_ba(bmap, problem, result)
            apply_ms = 1e3 * (time.process_time() - t)
            error_after = float(np.median([np.linalg.norm(bmap.keyframes[k].T_world_cam[:3, 3] - poses[k][:3, 3]) for k in bmap.keyframes]))
            row = {
                "n_keyframes": n_keyframes, "n_points": len(problem.problem.point_ids), "variant": variant,
                "n_observations": len(problem.problem.obs_keyframe), "build_cpu_ms": build_ms, "run_cpu_ms": run_ms,
                "run_wall_ms": run_wall_ms, "apply_cpu_ms": apply_ms, "iterations": result.stats["iterations"],
                "pose_error_before_m": error_before, "pose_error_after_m": error_after,
                "initial_error": result.stats["initial_error"], "final_error": result.stats["final_error"],
            }  # fmt: skip
            rows.append(row)
            print(
                f"global BA {n_keyframes:4d} kf {row['n_points']:6d} points {row['n_observations']:7d} obs {variant:17s}: "
                f"build {build_ms:6.0f} ms, run {run_ms:7.0f} ms cpu ({run_wall_ms:.0f} wall, {row['iterations']} iterations), "
                f"apply {apply_ms:5.0f} ms; error {row['initial_error']:.3g} -> {row['final_error']:.3g}, "
                f"median pose error {100 * error_before:.2f} -> {100 * error_after:.2f} cm",
                flush=True,
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller sizes, one seed")
    parser.add_argument("--only", choices=["pose_graph", "sim3", "global_ba"], action="append", help="run only these parts")
    parser.add_argument("--variants", choices=list(POSE_GRAPH_VARIANTS), action="append", help="pose-graph variants (default all)")
    parser.add_argument("--sizes", type=int, nargs="+", help="pose-graph keyframe counts (default 500; --quick 200)")
    args = parser.parse_args()
    parts = args.only or ["pose_graph", "sim3", "global_ba"]
    out: dict = {"machine": platform.processor() or platform.machine(), "environment": environment.describe(), "quick": args.quick}
    if "pose_graph" in parts:
        sizes, seeds = ((200,), (0,)) if args.quick else ((500,), (0, 1, 2))
        out["pose_graph"] = bench_pose_graph(args.sizes or sizes, seeds, args.variants or list(POSE_GRAPH_VARIANTS))
    if "sim3" in parts:
        out["sim3"] = bench_sim3((100,) if args.quick else (100, 200, 400), range(5 if args.quick else 20))
    if "global_ba" in parts:
        sizes = ((100, 2000),) if args.quick else ((100, 2000), (300, 2000), (300, 10000))
        out["global_ba"] = bench_global_ba(sizes, ["default"] if args.quick else list(GLOBAL_BA_VARIANTS))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=1))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
