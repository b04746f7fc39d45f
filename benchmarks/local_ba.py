"""Benchmark local bundle adjustment: batch Levenberg-Marquardt over the window against iSAM2 keyframe by keyframe.

Synthetic windows with known truth, sized like the ones local mapping hands over:

- ``kitti_*``: KITTI's rectified camera (1226x370, fx 707, 0.537 m baseline), a car driving 1.5 m
  between keyframes with a slow yaw, points on a 40 m wide strip 3-60 m ahead (log-uniform in
  depth); observations nearer than 40 baselines are stereo (ORB-SLAM's close points), farther
  ones monocular.
- ``room``: the synthetic room camera (640x480, fx 460, 0.10 m baseline), keyframes 0.15 m apart,
  points 1.5-6 m away.

Noise is 1 px x 1.2**level (pyramid levels 0-7), 5% gross outliers (15-60 px off). Two starts:
``cold``, every free pose 5 cm / 1 deg off and every point 5 cm off (the first ``n_fixed``
keyframes exact and fixed); ``warm``, the steady state of local mapping -- the window at its
optimum except the newest keyframe (2 cm / 0.2 deg off) and the points it sees first (5 cm off).
Times are medians over seeds; ``cpu_ms`` is process CPU time (the machine is shared, wall time
``time_ms`` includes waiting for a core).

Variants:
- ``schur_lm`` (the default): ``zenslam.backend.schur_ba.SchurBundleAdjuster``, the steps below
  solved on the reduced camera system in numpy.
- ``batch_lm``: ``zenslam.backend.local_ba.LocalBundleAdjuster`` with its defaults (ORB-SLAM's two
  passes, 5 robust iterations, outlier removal, 10 plain ones, as caps with a 1e-3 relative stop;
  landmarks-first ordering; sequential Cholesky; damping floor 1e-2).
- ``batch_lm_orbslam_iterations``: the fixed 5 + 10 iterations with gtsam's default damping.
- ``batch_lm_colamd`` / ``batch_lm_multifrontal_cholesky``: the default with gtsam's COLAMD
  ordering / with multifrontal elimination.
- ``isam2_incremental``: one ``gtsam.ISAM2`` fed keyframe by keyframe (the new pose, the new
  landmarks once well triangulated -- two views, one stereo or 3 degrees apart, else Gauss-Newton
  finds them indeterminate --, their observations with Huber noise), each update with
  ``ISAM2UpdateParams.constrainedKeys`` = {newest pose} (the ordering fix of FINDINGS) and
  relinearizeSkip 1. Reported: the CPU time of each update (the per-keyframe cost), the accuracy
  after the last one, and whether an update raised. ``isam2_incremental_oracle_inliers`` is the
  same without the true outliers (iSAM2 has no outlier pass; this is its best case).

Run: ``.venv/bin/python benchmarks/local_ba.py`` (writes benchmarks/results/local_ba.json);
``--quick`` runs one repeat of the smallest windows.

``--stages`` instead times what one Levenberg-Marquardt iteration of gtsam's solver (batch_lm) is made
of, on the cold windows (CPU time, medians over repeats): building the robust pass's graph,
linearising it, eliminating the landmarks (the Schur complement onto the poses), eliminating the
poses, and evaluating the nonlinear error; with the cost per landmark and per observation, and the
whole default solve with its iteration count for scale (writes benchmarks/results/local_ba_stages.json).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np

from zenslam.backend import gtsam_keys
from zenslam.backend.local_ba import BAProblem, LocalBAConfig, LocalBundleAdjuster, first_pass_graph
from zenslam.backend.local_mapping import bundle_adjuster
from zenslam.camera import PinholeCalibration
from zenslam.geometry import make_T, so3_exp, so3_log

KITTI = PinholeCalibration(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370, baseline_m=0.5372)
ROOM = PinholeCalibration(460.0, 460.0, 320.0, 240.0, 640, 480, baseline_m=0.10)
RESULTS = Path(__file__).resolve().parent / "results" / "local_ba.json"
STAGES = RESULTS.with_name("local_ba_stages.json")


@dataclass(frozen=True)
class WindowSpec:
    """Size and geometry of one synthetic window."""

    name: str
    calibration: PinholeCalibration
    n_keyframes: int
    n_points: int
    target_observations: int
    n_fixed: int
    step_m: float  # camera motion between keyframes (m)
    forward: bool  # True: drive along the optical axis (KITTI); False: sideways (room)
    depth_range_m: tuple[float, float]
    lateral_half_width_m: float


SPECS = (
    WindowSpec("kitti_10kf", KITTI, 10, 1500, 6000, 2, 1.5, True, (3.0, 60.0), 20.0),
    WindowSpec("kitti_15kf", KITTI, 15, 2500, 10000, 3, 1.5, True, (3.0, 60.0), 20.0),
    WindowSpec("kitti_20kf", KITTI, 20, 3000, 12000, 4, 1.5, True, (3.0, 60.0), 20.0),
    WindowSpec("room_10kf", ROOM, 10, 800, 4000, 2, 0.15, False, (1.5, 6.0), 4.0),
)


@dataclass(frozen=True)
class Window:
    """A synthetic problem with its truth."""

    problem: BAProblem
    T_true: np.ndarray  # (K, 4, 4) T_world_cam
    p_true: np.ndarray  # (P, 3)
    outlier: np.ndarray  # (O,) bool


def make_window(spec: WindowSpec, seed: int) -> Window:
    """Draw a window: trajectory, points in view, observations with noise and outliers, perturbed start."""
    rng = np.random.default_rng(seed)
    c = spec.calibration
    K = spec.n_keyframes
    step = np.array([0.0, 0.0, spec.step_m]) if spec.forward else np.array([spec.step_m, 0.0, 0.2 * spec.step_m])
    T_true = np.stack([make_T(so3_exp([0.0, 0.01 * k, 0.0]), k * step) for k in range(K)])
    near, far = spec.depth_range_m
    span = K * spec.step_m if spec.forward else 0.0
    sideways_span = 0.0 if spec.forward else K * spec.step_m
    p_true = np.stack(
        [
            rng.uniform(-spec.lateral_half_width_m, spec.lateral_half_width_m + sideways_span, 4 * spec.n_points),
            rng.uniform(-3.0 if spec.forward else -2.0, 1.6 if spec.forward else 2.0, 4 * spec.n_points),
            # Log-uniform depth: most features are near (road, cars, walls), as on KITTI.
            np.exp(rng.uniform(np.log(near), np.log(far + span), 4 * spec.n_points)),
        ],
        axis=1,
    )
    obs_kf, obs_pt, px, z = _visible(T_true, p_true, c, far)
    counts = np.bincount(obs_pt, minlength=len(p_true))
    # Keep points seen by two keyframes or more (local points), then thin observations to the target.
    candidates = np.flatnonzero(counts >= 2)
    keep_points = np.sort(rng.choice(candidates, min(spec.n_points, len(candidates)), replace=False))
    remap = np.full(len(p_true), -1)
    remap[keep_points] = np.arange(len(keep_points))
    rows = np.flatnonzero(remap[obs_pt] >= 0)
    if len(rows) > spec.target_observations:
        rows = np.sort(rng.choice(rows, spec.target_observations, replace=False))
    obs_kf, obs_pt, px, z = obs_kf[rows], remap[obs_pt[rows]], px[rows], z[rows]
    p_true = p_true[keep_points]
    return _observe(spec, rng, T_true, p_true, obs_kf, obs_pt, px, z)


def warm_start(window: Window, seed: int) -> Window:
    """The window as local mapping hands it over in steady state: already optimised except what is new.

    Every pose and point starts at the converged solution of the window (LM from the truth), except
    the newest keyframe (2 cm / 0.2 deg off, as after tracking's pose optimisation) and the points
    it sees first (new points, 5 cm off).
    """
    rng = np.random.default_rng(seed + 1000)
    problem = window.problem
    start = dataclasses.replace(problem, T_world_cam=window.T_true.copy(), p_world=window.p_true.copy())
    reference = LocalBundleAdjuster(LocalBAConfig(robust_iterations=30, refine_iterations=30)).optimize(start)
    T_init, p_init = reference.T_world_cam.copy(), reference.p_world.copy()
    newest = len(T_init) - 1
    T_init[newest] = T_init[newest] @ _perturbation(rng, 0.2, 0.02)
    first_seen = np.full(len(p_init), newest + 1)
    np.minimum.at(first_seen, problem.obs_point, problem.obs_keyframe)
    new = first_seen == newest
    offsets = rng.normal(size=(int(new.sum()), 3))
    p_init[new] += 0.05 * offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    return dataclasses.replace(window, problem=dataclasses.replace(problem, T_world_cam=T_init, p_world=p_init))


def _visible(T_true, p_true, c, max_depth):
    """Every (keyframe, point) pair where the point projects inside the image within max_depth."""
    kf, pt = np.meshgrid(np.arange(len(T_true)), np.arange(len(p_true)), indexing="ij")
    kf, pt = kf.ravel(), pt.ravel()
    p_cam = np.einsum("nji,nj->ni", T_true[kf, :3, :3], p_true[pt] - T_true[kf, :3, 3])
    z = p_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        px = np.stack([c.fx * p_cam[:, 0] / z + c.cx, c.fy * p_cam[:, 1] / z + c.cy], 1)
    seen = (z > 0.5) & (z < max_depth) & (px[:, 0] >= 0) & (px[:, 0] < c.width) & (px[:, 1] >= 0) & (px[:, 1] < c.height)
    return kf[seen], pt[seen], px[seen], z[seen]


def _observe(spec, rng, T_true, p_true, obs_kf, obs_pt, px, z) -> Window:
    """Noisy observations, outliers and a perturbed initial estimate for the chosen pairs."""
    c = spec.calibration
    n = len(obs_kf)
    level = rng.integers(0, 8, n)
    sigma = 1.2**level
    obs_px = px + rng.normal(size=(n, 2)) * sigma[:, None]
    stereo = z < 40.0 * c.baseline_m
    obs_right_u = np.where(stereo, px[:, 0] - c.bf / z + rng.normal(size=n) * sigma, np.nan)
    outlier = rng.random(n) < 0.05
    obs_px[outlier] += rng.uniform(15.0, 60.0, (int(outlier.sum()), 2)) * rng.choice([-1.0, 1.0], (int(outlier.sum()), 2))
    fixed = np.arange(len(T_true)) < spec.n_fixed
    T_init = T_true.copy()
    for k in np.flatnonzero(~fixed):
        T_init[k] = T_true[k] @ _perturbation(rng, 1.0, 0.05)
    offsets = rng.normal(size=p_true.shape)
    p_init = p_true + 0.05 * offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    problem = BAProblem(
        calibration=c,
        keyframe_ids=np.arange(100, 100 + len(T_true), dtype=np.int64),
        T_world_cam=T_init,
        fixed=fixed,
        point_ids=np.arange(len(p_true), dtype=np.int64) * 3 + 1,
        p_world=p_init,
        obs_keyframe=obs_kf,
        obs_point=obs_pt,
        obs_px=obs_px,
        obs_right_u=obs_right_u,
        obs_inv_sigma2=sigma**-2.0,
    )
    return Window(problem, T_true, p_true, outlier)


def _perturbation(rng: np.random.Generator, angle_deg: float, distance_m: float) -> np.ndarray:
    """A rigid motion by angle_deg about a random axis and distance_m along a random direction."""
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    R = so3_exp(np.deg2rad(angle_deg) * axis / np.linalg.norm(axis))
    return make_T(R, distance_m * direction / np.linalg.norm(direction))


def accuracy(window: Window, T_world_cam: np.ndarray, p_world: np.ndarray) -> dict:
    """Pose errors of the free keyframes (cm, deg) and the median point error (cm) against the truth."""
    free = ~window.problem.fixed
    position = np.linalg.norm(T_world_cam[free, :3, 3] - window.T_true[free, :3, 3], axis=1)
    pairs = zip(T_world_cam[free], window.T_true[free])
    rotation = [np.rad2deg(np.linalg.norm(so3_log(a[:3, :3].T @ b[:3, :3]))) for a, b in pairs]
    return {
        "pose_cm_median": 100 * float(np.median(position)),
        "pose_cm_max": 100 * float(np.max(position)),
        "rotation_deg_max": float(np.max(rotation)),
        "point_cm_median": 100 * float(np.median(np.linalg.norm(p_world - window.p_true, axis=1))),
    }


def run_batch(window: Window, config: LocalBAConfig) -> dict:
    """One batch solve; wall and CPU time, iterations, accuracy and outlier recall."""
    cpu_start = time.process_time()
    result = bundle_adjuster(config).optimize(window.problem)
    cpu_ms = 1e3 * (time.process_time() - cpu_start)
    out = {
        "time_ms": result.stats["time_ms"],
        "cpu_ms": cpu_ms,
        "iterations": result.stats["iterations"],
        "final_error": result.stats["final_error"],
        "failed": float(result.stats["failure"] is not None),
    }
    out.update(accuracy(window, result.T_world_cam, result.p_world))
    out["outlier_recall"] = float((~result.inlier_obs[window.outlier]).mean())
    out["inlier_kept"] = float(result.inlier_obs[~window.outlier].mean())
    return out


def run_isam2(window: Window, oracle_inliers: bool) -> dict:
    """iSAM2 fed keyframe by keyframe; per-update CPU times and the accuracy after the last update.

    ``oracle_inliers``: leave the true gross outliers out (iSAM2 has no outlier pass of its own).
    """
    problem = window.problem
    c = problem.calibration
    cal_mono = gtsam.Cal3_S2(c.fx, c.fy, 0.0, c.cx, c.cy)
    cal_stereo = gtsam.Cal3_S2Stereo(c.fx, c.fy, 0.0, c.cx, c.cy, c.baseline_m)
    params = gtsam.ISAM2Params()
    params.relinearizeSkip = 1
    isam = gtsam.ISAM2(params)
    stereo = np.isfinite(problem.obs_right_u)
    point_keys = gtsam_keys.landmark_keys(problem.point_ids)
    added = np.zeros(len(problem.point_ids), dtype=bool)
    pending: dict[int, list[int]] = {}
    update_ms = []
    for k in range(len(problem.keyframe_ids)):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        x = gtsam_keys.pose_key(problem.keyframe_ids[k])
        pose = gtsam.Pose3(problem.T_world_cam[k])
        values.insert(x, pose)
        if problem.fixed[k]:
            graph.add(gtsam.NonlinearEqualityPose3(x, pose))
        # With outliers in, a landmark whose factors Huber down-weights can make iSAM2's undamped
        # Gauss-Newton system indeterminate; the oracle variant shows the best case.
        rows = (problem.obs_keyframe == k) & ~(window.outlier & oracle_inliers)
        for row in np.flatnonzero(rows).tolist():
            j = int(problem.obs_point[row])
            pending.setdefault(j, []).append(row)
            if not added[j] and not _well_triangulated(problem, j, pending[j], stereo):
                continue  # Gauss-Newton needs a well-determined point: wait for more views
            if not added[j]:
                values.insert(point_keys[j], gtsam.Point3(problem.p_world[j]))
                added[j] = True
            for r in pending.pop(j):
                graph.add(_isam2_factor(problem, r, stereo[r], point_keys[j], cal_mono, cal_stereo))
        update = gtsam.ISAM2UpdateParams()
        constrained = gtsam.KeyGroupMap()
        constrained.insert2(x, 1)
        update.constrainedKeys = constrained
        start = time.process_time()
        try:
            isam.update(graph, values, update)
        except RuntimeError as exc:  # IndeterminantLinearSystemException: iSAM2 has no damping to fall back on
            return {"failed": 1.0, "failed_at_keyframe": float(k), "error": " ".join(str(exc).split())[:100]}
        update_ms.append(1e3 * (time.process_time() - start))
    estimate = isam.calculateEstimate()
    T = np.stack([estimate.atPose3(gtsam_keys.pose_key(i)).matrix() for i in problem.keyframe_ids])
    p = problem.p_world.copy()
    for j in np.flatnonzero(added).tolist():
        p[j] = estimate.atPoint3(point_keys[j])
    out = {  # CPU milliseconds per update
        "failed": 0.0,
        "update_cpu_ms_median": statistics.median(update_ms),
        "update_cpu_ms_last": update_ms[-1],
        "update_cpu_ms_max": max(update_ms),
        "cpu_ms_total": sum(update_ms),
        "landmarks_not_added": int((~added).sum()),
    }
    out.update(accuracy(window, T, p))
    return out


def _well_triangulated(problem: BAProblem, point: int, rows: list[int], stereo: np.ndarray) -> bool:
    """Two views, one of them stereo or 3 degrees apart: a landmark iSAM2's Gauss-Newton can take."""
    return len(rows) >= 2 and (bool(stereo[rows].any()) or _parallax_deg(problem, point, rows) > 3.0)


def _parallax_deg(problem: BAProblem, point: int, rows: list[int]) -> float:
    """Largest angle (deg) between the rays from the observing keyframes' centres to the point's initial position."""
    centres = problem.T_world_cam[problem.obs_keyframe[rows], :3, 3]
    rays = problem.p_world[point] - centres
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    return float(np.rad2deg(np.arccos(np.clip((rays @ rays.T).min(), -1.0, 1.0))))


def _isam2_factor(problem, row, is_stereo, point_key, cal_mono, cal_stereo):
    x = gtsam_keys.pose_key(problem.keyframe_ids[problem.obs_keyframe[row]])
    sigma = 1.0 / np.sqrt(problem.obs_inv_sigma2[row])
    u, v = problem.obs_px[row]
    dim = 3 if is_stereo else 2
    huber = gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(7.815 if is_stereo else 5.991))
    noise = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Isotropic.Sigma(dim, sigma))
    if is_stereo:
        return gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(u, problem.obs_right_u[row], v), noise, x, point_key, cal_stereo)
    return gtsam.GenericProjectionFactorCal3_S2(np.array([u, v]), noise, x, point_key, cal_mono)


def solver_stages(problem: BAProblem, config: LocalBAConfig) -> dict:
    """CPU milliseconds of the stages of one linear solve of the robust pass's graph, and of the whole
    solve with ``config`` (``LocalBundleAdjuster.optimize``) with its iteration count."""

    def timed(run):
        start = time.process_time()
        out = run()
        return out, 1e3 * (time.process_time() - start)

    (graph, values, ordering), build_ms = timed(lambda: first_pass_graph(problem, config))
    linear, linearize_ms = timed(lambda: graph.linearize(values))
    landmark_keys = set(gtsam_keys.landmark_keys(problem.point_ids))
    keys = [ordering.at(i) for i in range(ordering.size())]
    landmarks, poses = gtsam.Ordering(), gtsam.Ordering()
    for key in keys:
        (landmarks if key in landmark_keys else poses).push_back(key)
    n_landmarks = landmarks.size()
    (_, on_poses), landmarks_ms = timed(lambda: linear.eliminatePartialSequential(landmarks))
    _, poses_ms = timed(lambda: on_poses.eliminateSequential(poses))
    _, error_ms = timed(lambda: graph.error(values))
    result, solve_ms = timed(lambda: LocalBundleAdjuster(config).optimize(problem))
    n_observations = int(graph.size()) - int(problem.fixed.sum())
    return {
        "build_ms": build_ms,
        "linearize_ms": linearize_ms,
        "eliminate_landmarks_ms": landmarks_ms,
        "eliminate_poses_ms": poses_ms,
        "error_ms": error_ms,
        "landmarks": n_landmarks,
        "observation_factors": n_observations,
        "eliminate_us_per_landmark": 1e3 * landmarks_ms / max(n_landmarks, 1),
        "linearize_us_per_observation": 1e3 * linearize_ms / max(n_observations, 1),
        "solve_ms": solve_ms,
        "solve_iterations": result.stats["iterations"],
    }


def summarise(runs: list[dict]) -> dict:
    """Median of every figure over the repeats that did not fail, and the number that failed."""
    ok = [r for r in runs if not r.get("failed")]
    out = {key: statistics.median(r[key] for r in ok) for key in ok[0]} if ok else {}
    out["failed"] = len(runs) - len(ok)
    return out


def write_stages(specs: list[WindowSpec], repeats: int) -> None:
    """Print and write the solver's stages on each spec's cold windows (``--stages``)."""
    results: dict = {
        "machine": {"python": platform.python_version(), "processor": platform.machine(), "load_avg_at_start": os.getloadavg()},
        "units": "CPU milliseconds (microseconds where named); medians over repeats",
        "windows": {},
    }
    for spec in specs:
        runs = [solver_stages(make_window(spec, seed).problem, LocalBAConfig(method="batch_lm")) for seed in range(repeats)]
        entry = summarise(runs)
        results["windows"][spec.name] = entry
        print(
            f"{spec.name}: {entry['landmarks']:.0f} landmarks, {entry['observation_factors']:.0f} observations; per solve: "
            f"build {entry['build_ms']:.1f} ms, linearize {entry['linearize_ms']:.1f}, "
            f"landmarks {entry['eliminate_landmarks_ms']:.1f} ({entry['eliminate_us_per_landmark']:.1f} us each), "
            f"poses {entry['eliminate_poses_ms']:.1f}, error {entry['error_ms']:.1f}; "
            f"whole default solve {entry['solve_ms']:.1f} ms in {entry['solve_iterations']:.0f} iterations",
            flush=True,
        )
    STAGES.parent.mkdir(parents=True, exist_ok=True)
    STAGES.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {STAGES}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="one repeat of the smallest windows")
    parser.add_argument("--stages", action="store_true", help="time the stages of one solve instead (see the module doc)")
    args = parser.parse_args()
    specs = [s for s in SPECS if s.name in ("kitti_10kf", "room_10kf")] if args.quick else list(SPECS)
    repeats = 1 if args.quick else args.repeats
    if args.stages:
        write_stages(specs, repeats)
        return
    variants = {
        "schur_lm": LocalBAConfig(),  # the default
        "batch_lm": LocalBAConfig(method="batch_lm"),
        # ORB-SLAM's fixed 5 + 10 iterations with gtsam's default damping schedule.
        "batch_lm_orbslam_iterations": LocalBAConfig(
            method="batch_lm", relative_error_tolerance=1e-5, lambda_initial=1e-5, lambda_lower_bound=0.0
        ),
        "batch_lm_colamd": LocalBAConfig(method="batch_lm", ordering="colamd"),
        "batch_lm_multifrontal_cholesky": LocalBAConfig(method="batch_lm", linear_solver="multifrontal_cholesky"),
    }
    results: dict = {
        "machine": {"python": platform.python_version(), "processor": platform.machine(), "load_avg_at_start": os.getloadavg()},
        "units": "milliseconds (time_ms wall, cpu_ms process CPU), centimetres, degrees; medians over repeats",
        "windows": {},
    }
    for spec in specs:
        cold = [make_window(spec, seed) for seed in range(repeats)]
        for start, windows in (("cold", cold), ("warm", [warm_start(w, i) for i, w in enumerate(cold)])):
            p = windows[0].problem
            entry: dict = {
                "keyframes": spec.n_keyframes,
                "fixed": spec.n_fixed,
                "points": len(p.point_ids),
                "observations": len(p.obs_point),
                "stereo_fraction": float(np.isfinite(p.obs_right_u).mean()),
            }
            for name, config in variants.items():
                entry[name] = summarise([run_batch(w, config) for w in windows])
                print(spec.name, start, name, json.dumps(entry[name]), flush=True)
            if start == "cold":
                for name, oracle in (("isam2_incremental", False), ("isam2_incremental_oracle_inliers", True)):
                    entry[name] = summarise([run_isam2(w, oracle) for w in windows])
                    print(spec.name, start, name, json.dumps(entry[name]), flush=True)
            results["windows"][f"{spec.name}_{start}"] = entry
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
