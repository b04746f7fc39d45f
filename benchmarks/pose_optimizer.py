"""Benchmark pose-only optimisation: zenslam's Levenberg-Marquardt against two gtsam factor graphs.

Each solver runs ORB-SLAM2's schedule (4 rounds x 10 iterations, Huber in the first 3 rounds,
chi-square outlier classification after each round) on synthetic stereo+mono scenes with 30%
gross outliers, 1 px noise and an initial pose 10 cm / 5 degrees off. Variants:

- ``numpy_lm``: ``zenslam.pose_optimizer.optimize_pose`` (the implementation kept: numpy around a
  compiled pass for its normal equations, ``pose_normal_equations``; the key keeps its old name).
- ``gtsam_custom``: one Pose3 variable, one ``gtsam.CustomFactor`` per observation with analytic
  Jacobians in Python, Huber noise models, gtsam's LM (10 iterations per round).
- ``gtsam_builtin``: C++ ``GenericProjectionFactorCal3_S2`` / ``GenericStereoFactor3D``, each map
  point a variable held by ``NonlinearEqualityPoint3`` (exactly fixed), LM with QR elimination.

Run: ``.venv/bin/python benchmarks/pose_optimizer.py`` (writes benchmarks/results/pose_optimizer.json).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import gtsam
import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.pose_optimizer import PoseOptimizerConfig, optimize_pose
from zenslam.geometry import invert_T, make_T, so3_exp, so3_log

KITTI = PinholeCalibration(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370, baseline_m=0.5372)
RESULTS = Path(__file__).resolve().parent / "results" / "pose_optimizer.json"


def make_scene(n: int, seed: int, calibration: PinholeCalibration = KITTI) -> dict:
    """Synthetic observations of n points: 50% stereo, 1 px noise, 30% gross outliers, perturbed start."""
    rng = np.random.default_rng(seed)
    T_cam_world = make_T(so3_exp(rng.normal(scale=0.3, size=3)), rng.normal(scale=5.0, size=3))
    u = rng.uniform(0, calibration.width, n)
    v = rng.uniform(0, calibration.height, n)
    z = rng.uniform(2.0, 40.0, n)
    p_cam = np.stack([(u - calibration.cx) * z / calibration.fx, (v - calibration.cy) * z / calibration.fy, z], 1)
    p_world = (p_cam - T_cam_world[:3, 3]) @ T_cam_world[:3, :3]
    level = rng.integers(0, 8, n)
    obs_px = np.stack([u, v], 1) + rng.normal(size=(n, 2))
    stereo = rng.random(n) < 0.5
    obs_right_u = np.where(stereo, u - calibration.bf / z + rng.normal(size=n), -1.0)
    outlier = rng.random(n) < 0.3
    obs_px[outlier] = rng.uniform([0, 0], [calibration.width, calibration.height], (int(outlier.sum()), 2))
    bad_stereo = outlier & stereo
    obs_right_u[bad_stereo] = obs_px[bad_stereo, 0] - rng.uniform(1.0, 100.0, int(bad_stereo.sum()))
    axis = rng.normal(size=3)
    direction = rng.normal(size=3)
    delta = make_T(so3_exp(np.deg2rad(5.0) * axis / np.linalg.norm(axis)), 0.1 * direction / np.linalg.norm(direction))
    return {
        "T_true": T_cam_world,
        "T_init": delta @ T_cam_world,
        "p_world": p_world,
        "obs_px": obs_px,
        "obs_right_u": obs_right_u,
        "inv_sigma2": 1.2 ** (-2.0 * level),
        "outlier": outlier,
    }


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Camera position error (m) and rotation error (deg) between two T_cam_world."""
    position = float(np.linalg.norm(invert_T(T_est)[:3, 3] - invert_T(T_true)[:3, 3]))
    rotation = float(np.rad2deg(np.linalg.norm(so3_log(T_est[:3, :3] @ T_true[:3, :3].T))))
    return position, rotation


def chi2_numpy(T_cam_world, scene, calibration) -> np.ndarray:
    """Information-weighted squared error per observation (inf behind the camera)."""
    p_cam = scene["p_world"] @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    z = p_cam[:, 2]
    u = calibration.fx * p_cam[:, 0] / z + calibration.cx
    v = calibration.fy * p_cam[:, 1] / z + calibration.cy
    err = (u - scene["obs_px"][:, 0]) ** 2 + (v - scene["obs_px"][:, 1]) ** 2
    stereo = scene["obs_right_u"] >= 0
    err = err + np.where(stereo, (u - calibration.bf / z - scene["obs_right_u"]) ** 2, 0.0)
    return np.where(z > 0, scene["inv_sigma2"] * err, np.inf)


def _classify(T_cam_world, scene, calibration, config) -> np.ndarray:
    threshold = np.where(scene["obs_right_u"] >= 0, config.chi2_stereo, config.chi2_mono)
    return chi2_numpy(T_cam_world, scene, calibration) <= threshold


def _noise(dim: int, inv_sigma2: float, robust: bool, chi2: float):
    base = gtsam.noiseModel.Isotropic.Sigma(dim, 1.0 / np.sqrt(inv_sigma2))
    if not robust:
        return base
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(chi2)), base)


def _custom_error(p_world, measured, calibration, stereo):
    """CustomFactor error function on X = T_cam_world with the right-perturbation Jacobian."""
    fx, fy, cx, cy = calibration.fx, calibration.fy, calibration.cx, calibration.cy
    bf = calibration.bf

    def error(this, values, jacobians):
        pose = values.atPose3(this.keys()[0])
        R = pose.rotation().matrix()
        x, y, z = R @ p_world + pose.translation()
        pred = [fx * x / z + cx, fy * y / z + cy]
        d_proj = [[fx / z, 0.0, -fx * x / z**2], [0.0, fy / z, -fy * y / z**2]]
        if stereo:
            pred.append(pred[0] - bf / z)
            d_proj.append([fx / z, 0.0, (bf - fx * x) / z**2])
        if jacobians is not None:
            px, py, pz = p_world
            skew_p = np.array([[0.0, -pz, py], [pz, 0.0, -px], [-py, px, 0.0]])
            jacobians[0] = np.array(d_proj) @ np.hstack([-R @ skew_p, R])
        return np.array(pred) - measured

    return error


def _lm(graph, values, iterations: int, qr: bool) -> gtsam.Values:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    if qr:
        params.setLinearSolverType("MULTIFRONTAL_QR")
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def solve_gtsam_custom(scene, calibration, config) -> np.ndarray:
    """ORB-SLAM2's rounds with one CustomFactor per observation; returns T_cam_world."""
    key = gtsam.symbol("x", 0)
    stereo = scene["obs_right_u"] >= 0
    active = np.ones(len(stereo), dtype=bool)
    T = scene["T_init"]
    for round_index in range(config.rounds):
        robust = round_index < config.robust_rounds
        graph = gtsam.NonlinearFactorGraph()
        for i in np.flatnonzero(active):
            measured = np.append(scene["obs_px"][i], scene["obs_right_u"][i]) if stereo[i] else scene["obs_px"][i]
            chi2 = config.chi2_stereo if stereo[i] else config.chi2_mono
            noise = _noise(len(measured), scene["inv_sigma2"][i], robust, chi2)
            error = _custom_error(scene["p_world"][i], measured, calibration, bool(stereo[i]))
            graph.add(gtsam.CustomFactor(noise, [key], error))
        values = gtsam.Values()
        values.insert(key, gtsam.Pose3(T))
        T = _lm(graph, values, config.iterations_per_round, qr=False).atPose3(key).matrix()
        active = _classify(T, scene, calibration, config)
    return T


def solve_gtsam_builtin(scene, calibration, config) -> np.ndarray:
    """ORB-SLAM2's rounds with gtsam's C++ factors and exactly fixed landmarks; returns T_cam_world."""
    X = gtsam.symbol("x", 0)
    K = gtsam.Cal3_S2(calibration.fx, calibration.fy, 0.0, calibration.cx, calibration.cy)
    K_stereo = gtsam.Cal3_S2Stereo(
        calibration.fx, calibration.fy, 0.0, calibration.cx, calibration.cy, calibration.baseline_m
    )
    stereo = scene["obs_right_u"] >= 0
    active = np.ones(len(stereo), dtype=bool)
    T_world_cam = invert_T(scene["T_init"])  # gtsam's camera factors take the camera's pose in the world
    for round_index in range(config.rounds):
        robust = round_index < config.robust_rounds
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        values.insert(X, gtsam.Pose3(T_world_cam))
        for i in np.flatnonzero(active):
            L = gtsam.symbol("l", int(i))
            u, v = scene["obs_px"][i]
            if stereo[i]:
                noise = _noise(3, scene["inv_sigma2"][i], robust, config.chi2_stereo)
                measured = gtsam.StereoPoint2(u, scene["obs_right_u"][i], v)
                graph.add(gtsam.GenericStereoFactor3D(measured, noise, X, L, K_stereo, False, False))
            else:
                noise = _noise(2, scene["inv_sigma2"][i], robust, config.chi2_mono)
                graph.add(gtsam.GenericProjectionFactorCal3_S2(np.array([u, v]), noise, X, L, K, False, False))
            graph.add(gtsam.NonlinearEqualityPoint3(L, scene["p_world"][i]))
            values.insert(L, scene["p_world"][i])
        T_world_cam = _lm(graph, values, config.iterations_per_round, qr=True).atPose3(X).matrix()
        active = _classify(invert_T(T_world_cam), scene, calibration, config)
    return invert_T(T_world_cam)


def solve_numpy(scene, calibration, config) -> np.ndarray:
    """The kept implementation."""
    result = optimize_pose(
        scene["T_init"], scene["p_world"], scene["obs_px"], scene["obs_right_u"], scene["inv_sigma2"],
        calibration, config,
    )
    return result.T_cam_world


SOLVERS = {"numpy_lm": solve_numpy, "gtsam_custom": solve_gtsam_custom, "gtsam_builtin": solve_gtsam_builtin}


def run(sizes: list[int], seeds: int, repeats: dict[str, int]) -> dict:
    """Time and score every solver on every (size, seed); returns the JSON-ready summary."""
    config = PoseOptimizerConfig()
    summary: dict = {"machine": platform.platform(), "python": platform.python_version(), "results": []}
    for n in sizes:
        for name, solver in SOLVERS.items():
            times_ms, pos_errs, rot_errs, recalls, kept = [], [], [], [], []
            for seed in range(seeds):
                scene = make_scene(n, seed)
                for _ in range(repeats[name]):
                    start = time.perf_counter()
                    T = solver(scene, KITTI, config)
                    times_ms.append((time.perf_counter() - start) * 1e3)
                position, rotation = pose_errors(T, scene["T_true"])
                inliers = _classify(T, scene, KITTI, config)
                pos_errs.append(position)
                rot_errs.append(rotation)
                recalls.append(float((~inliers[scene["outlier"]]).mean()))
                kept.append(float(inliers[~scene["outlier"]].mean()))
            row = {
                "solver": name,
                "n_points": n,
                "scenes": seeds,
                "ms_median": statistics.median(times_ms),
                "ms_min": min(times_ms),
                "position_error_m_max": max(pos_errs),
                "rotation_error_deg_max": max(rot_errs),
                "outlier_recall_min": min(recalls),
                "inliers_kept_min": min(kept),
            }
            summary["results"].append(row)
            print(json.dumps(row))
    by_key = {(r["solver"], r["n_points"]): r["ms_median"] for r in summary["results"]}
    summary["speedup_numpy_over_gtsam_custom"] = {
        str(n): by_key[("gtsam_custom", n)] / by_key[("numpy_lm", n)] for n in sizes
    }
    summary["speedup_numpy_over_gtsam_builtin"] = {
        str(n): by_key[("gtsam_builtin", n)] / by_key[("numpy_lm", n)] for n in sizes
    }
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[300, 800], help="observations per problem")
    parser.add_argument("--seeds", type=int, default=5, help="synthetic scenes per size")
    parser.add_argument("--output", type=Path, default=RESULTS, help="where to write the JSON summary")
    args = parser.parse_args()
    summary = run(args.sizes, args.seeds, {"numpy_lm": 10, "gtsam_custom": 1, "gtsam_builtin": 2})
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
