"""Local bundle adjustment: keyframe poses and map points of a covisibility window, with gtsam.

This is ``local_ba.method: batch_lm``, the reference: the default, ``schur_lm`` (``schur_ba``),
takes the same steps on the same problem and solves them on the reduced camera system in numpy,
faster (benchmarks/local_ba.md); global BA runs this one (see ``schur_ba`` for why).

The problem is ORB-SLAM's ``Optimizer::LocalBundleAdjustment``: the local keyframes' poses and
the local map points are variables, the other keyframes that see those points are held fixed,
and every observation is a reprojection factor -- ``gtsam.GenericStereoFactor3D`` for stereo /
RGB-D keypoints (uL, uR, v), ``gtsam.GenericProjectionFactorCal3_S2`` for monocular ones -- with
isotropic noise sigma = 1/sqrt(inv_sigma2) px under a Huber kernel. RGB-D's virtual uR = uL - bf / depth
is not a measurement of its own: it carries uL's keypoint error plus the depth sensor's, so those
rows get cov(uL, uR) = sigma^2 and var(uR) = sigma^2 + disparity_sigma^2 (``obs_disparity_sigma``).
(ORB-SLAM's isotropic model gives a far point's depth a sigma of tens of centimetres with a
10 cm virtual baseline and leaves it to the parallax between keyframes, which lets BA scale the map.)
Two passes as ORB-SLAM: a few robust iterations, then observations with chi2 above the 95%
threshold (5.991 for 2 dof, 7.815 for 3) or in front of no camera are dropped and the rest is
refined without the kernel.
The refinement runs even when the robust pass converged and dropped nothing: skipping it saves
little and costs accuracy. A refinement of one step (the default) runs on the robust pass's Huber
factors instead of kernel-free ones built anew: it linearizes where the robust pass ended, where
every inlier's whitened residual is within Huber's threshold (the inlier test's chi2 threshold is
its square), so Huber weighs each as the plain quadratic and the step is the kernel-free one; only
the step's acceptance test sees Huber's error, for residuals the step takes past the threshold.
Poses are gtsam ``Pose3`` = T_world_cam (the factors take the camera pose in the world). Fixed
keyframes stay variables held by ``NonlinearEqualityPose3`` (a hard constraint: no prior with a
made-up sigma changes the problem), and are copied to the result unchanged.

Which points are variables: a point is optimised when its active observations constrain it --
one stereo observation (depth from disparity) or two observations from distinct keyframes, fixed
ones included. A point with a single monocular observation is held where it is (its ray gives no
depth), and its observation is classified by its chi2 like every other.

Never raises on bad geometry. The factors do not throw on cheirality (gtsam's default: a point
behind the camera gives a constant error and zero Jacobians), the chi2 classification flags
such observations, and Levenberg-Marquardt's damping keeps weak points (two nearly parallel
rays) solvable. Should gtsam still fail -- ``IndeterminantLinearSystemException`` arrives in
Python as a RuntimeError whose message names the key, "near variable <key>" -- the landmark it
names is dropped (all its observations outliers, listed in ``removed_point_ids``) and the pass
retried; any other failure ends the optimisation with the estimate so far and
``stats["failure"]`` set. Invalid input (mis-shaped arrays, ids that do not index, non-finite
poses) is a bug upstream and raises ``ZenslamError`` when the ``BAProblem`` is built.

Solver choice (the measurements are in benchmarks/local_ba.md and ``benchmarks/local_ba.py``): batch
Levenberg-Marquardt over the window, rebuilt on every call, sequential Cholesky, landmarks
eliminated before poses, 5 + 1 iterations as caps (ORB-SLAM: 5 + 10) with a 1e-3
relative-decrease stop and a 1e-2 damping floor. Fixed iterations with gtsam's default damping,
gtsam's COLAMD ordering (it interleaves poses with landmarks) and multifrontal Cholesky were all
slower for the same pose accuracy. iSAM2 fed keyframe by keyframe fails on windows with outliers (Gauss-Newton has no
damping for a landmark that Huber down-weights) and was slower in total even without them; a
persistent iSAM2 would also have to mirror every point creation, fusion, culling and outlier
decision of local mapping by removing factors, so local BA keeps no state between calls, and its
factors are built anew for each window (reusing them made gtsam's solve slower).
"""

from __future__ import annotations

import logging
import math
import re
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from zenslam.backend import gtsam_keys
from zenslam.backend.ba_problem import BAProblem, BAResult, LocalBAConfig, ba_stats, constrained_points

logger = logging.getLogger(__name__)

_NEAR_VARIABLE = re.compile(r"near variable\s+(\d+)")


class LocalBundleAdjuster:
    """Runs local BA on windows handed over one at a time; keeps no state between calls."""

    def __init__(self, config: LocalBAConfig) -> None:
        self.config = config

    def optimize(self, problem: BAProblem) -> BAResult:
        """Optimise the non-fixed poses and the constrained points of ``problem`` (see module doc)."""
        start = time.perf_counter()
        config = self.config
        window = _Window.of(problem, config)
        state = _State(problem.T_world_cam.copy(), problem.p_world.copy())
        state.dropped_points |= ~np.isfinite(state.p_world).all(axis=1)
        active = window.usable.copy()
        schedule = [(True, config.robust_iterations)]
        if config.two_passes:
            schedule.append((False, config.refine_iterations))
        # A one-step refinement after a robust pass runs on that pass's Huber factors (see the module doc).
        reuse = config.two_passes and config.refine_iterations == 1 and config.robust_iterations > 0
        for robust, iterations in schedule:
            if iterations <= 0:
                continue
            kernel = robust or reuse
            _run_pass(window, state, active & ~state.dropped_points[problem.obs_point], kernel, iterations, config, robust and reuse)
            if not (robust and reuse):
                state.factors[kernel].clear()  # no pass needs these factors again
            active = window.classify(state) & ~state.dropped_points[problem.obs_point]
            if state.failure is not None:
                break
        T_world_cam = state.T_world_cam
        T_world_cam[problem.fixed] = problem.T_world_cam[problem.fixed]
        has_inlier = np.bincount(problem.obs_point[active], minlength=len(problem.point_ids)) > 0
        removed = problem.point_ids[~has_inlier]
        stats = state.stats(active, removed, time.perf_counter() - start, config)
        logger.debug("local BA: %s", stats)
        return BAResult(T_world_cam, state.p_world, active, removed, stats)


def first_pass_graph(problem: BAProblem, config: LocalBAConfig) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, gtsam.Ordering]:
    """The robust pass's factor graph, its initial values and the elimination ordering (landmarks,
    then free poses, then fixed ones), as ``LocalBundleAdjuster.optimize`` builds them for its
    first pass: for timing the solver's stages (``benchmarks/local_ba.py --stages``)."""
    window = _Window.of(problem, config)
    state = _State(problem.T_world_cam.copy(), problem.p_world.copy())
    graph, values, point_rows, pose_rows, _, _ = _build_graph(window, state, window.usable, True, config)
    return graph, values, _landmarks_first(window, point_rows, pose_rows)


@dataclass
class _State:
    """The estimate as it evolves over passes and retries, plus bookkeeping for the stats."""

    T_world_cam: np.ndarray
    p_world: np.ndarray
    dropped_points: np.ndarray = field(init=False)  # (P,) bool, removed from the optimisation for good
    iterations: int = 0
    retries: int = 0
    initial_error: float = math.nan
    final_error: float = math.nan
    failure: str | None = None
    passes: int = 0
    # Factors with (True) and without (False) the Huber kernel, by observation row: built once per
    # window, reused by a retried pass.
    factors: dict = field(default_factory=lambda: {True: {}, False: {}})
    # The last robust pass's graph and result, kept when the refinement runs on its factors: the
    # refinement takes them less its outliers instead of a graph and values built anew.
    last_graph: _PassGraph | None = None

    def __post_init__(self) -> None:
        self.dropped_points = np.zeros(len(self.p_world), dtype=bool)

    def stats(self, active: np.ndarray, removed: np.ndarray, seconds: float, config: LocalBAConfig) -> dict:
        return ba_stats(
            config, iterations=self.iterations, initial_error=self.initial_error, final_error=self.final_error,
            seconds=seconds, inlier_obs=active, removed_point_ids=removed, n_dropped_points=int(self.dropped_points.sum()),
            passes=self.passes, retries=self.retries, failure=self.failure,
        )


@dataclass(frozen=True)
class _PassGraph:
    """A pass's factor graph (observation factors in row order, then the fixed poses' equality
    factors) and its result values, for the next pass to shrink rather than build anew."""

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    rows: np.ndarray  # (F,) observation row of each observation factor, in factor order
    pose_rows: np.ndarray  # (K,) keyframe rows with a value
    point_rows: np.ndarray  # (L,) point rows with a value, in key order
    equality_index: dict[int, int]  # fixed keyframe row -> index of its equality factor
    robust: bool  # its factors carry the Huber kernel


@dataclass(frozen=True)
class _Window:
    """The problem's fixed data in the layout the passes use: keys, calibrations, masks."""

    problem: BAProblem
    pose_keys: list[int]
    point_keys: np.ndarray  # (P,) uint64
    point_row_of_key: dict[int, int]
    usable: np.ndarray  # (O,) bool: finite pixel and positive information
    stereo: np.ndarray  # (O,) bool
    right_sigma_scale: np.ndarray  # (O,) multiplier of the right u's sigma
    disparity_sigma: np.ndarray  # (O,) px, > 0 on RGB-D stereo rows (virtual right u), else 0
    chi2_threshold: np.ndarray  # (O,)
    min_depth_m: float
    cal_mono: gtsam.Cal3_S2
    cal_stereo: gtsam.Cal3_S2Stereo | None

    @staticmethod
    def of(problem: BAProblem, config: LocalBAConfig) -> _Window:
        c = problem.calibration
        info = problem.obs_inv_sigma2
        usable = np.isfinite(problem.obs_px).all(axis=1) & np.isfinite(info) & (info > 0)
        stereo = usable & np.isfinite(problem.obs_right_u)
        disparity = np.zeros(len(info)) if problem.obs_disparity_sigma is None else np.nan_to_num(problem.obs_disparity_sigma)
        # A stereo row needs the baseline; calibration.bf raises a CalibrationError for a mono camera.
        cal_stereo = gtsam.Cal3_S2Stereo(c.fx, c.fy, 0.0, c.cx, c.cy, c.bf / c.fx) if stereo.any() else None
        pose_keys = gtsam_keys.pose_keys(problem.keyframe_ids)
        point_keys = gtsam_keys.landmark_keys(problem.point_ids)
        return _Window(
            problem=problem,
            pose_keys=pose_keys,
            point_keys=np.array(point_keys, dtype=np.uint64),
            point_row_of_key={k: i for i, k in enumerate(point_keys)},
            usable=usable,
            stereo=stereo,
            right_sigma_scale=(
                np.ones(len(info)) if problem.obs_right_sigma_scale is None else problem.obs_right_sigma_scale
            ),
            disparity_sigma=np.where(stereo & (disparity > 0), disparity, 0.0),
            chi2_threshold=np.where(stereo, config.chi2_stereo, config.chi2_mono),
            min_depth_m=config.min_depth_m,
            cal_mono=gtsam.Cal3_S2(c.fx, c.fy, 0.0, c.cx, c.cy),
            cal_stereo=cal_stereo,
        )

    def chi2(self, state: _State) -> tuple[np.ndarray, np.ndarray]:
        """Information-weighted squared error per observation, and the point's depth in that camera (m)."""
        p, c = self.problem, self.problem.calibration
        T = state.T_world_cam[p.obs_keyframe]
        # p_cam = R^T (p_world - t) with R, t of each observation's T_world_cam.
        p_cam = np.einsum("nji,nj->ni", T[:, :3, :3], state.p_world[p.obs_point] - T[:, :3, 3])
        z = p_cam[:, 2]
        inv_z = 1.0 / np.where(np.abs(z) > 1e-12, z, 1e-12)
        u = c.fx * p_cam[:, 0] * inv_z + c.cx
        v = c.fy * p_cam[:, 1] * inv_z + c.cy
        du = u - p.obs_px[:, 0]
        chi2 = (du**2 + (v - p.obs_px[:, 1]) ** 2) * p.obs_inv_sigma2
        if self.cal_stereo is not None:
            du_right = u - c.bf * inv_z - np.nan_to_num(p.obs_right_u)
            right_chi2 = du_right**2 * p.obs_inv_sigma2 / self.right_sigma_scale**2
            # RGB-D: u and the virtual right u share the keypoint's error, so the independent
            # part is their difference (the disparity, from the depth sensor).
            rgbd = self.disparity_sigma > 0
            right_chi2[rgbd] = (du[rgbd] - du_right[rgbd]) ** 2 / self.disparity_sigma[rgbd] ** 2
            chi2 = chi2 + np.where(self.stereo, right_chi2, 0.0)
        return chi2, z

    def classify(self, state: _State) -> np.ndarray:
        """(O,) inlier mask at the current estimate: usable, in front of the camera, chi2 within threshold."""
        with np.errstate(invalid="ignore", over="ignore"):
            chi2, z = self.chi2(state)
            return self.usable & (z > self.min_depth_m) & (chi2 <= self.chi2_threshold)


def _run_pass(
    window: _Window, state: _State, active: np.ndarray, robust: bool, iterations: int, config: LocalBAConfig,
    keep_graph: bool = False,
) -> None:
    """One optimisation pass on the active observations, repairing what gtsam reports as degenerate;
    ``keep_graph``: keep its graph and result for the next pass (``state.last_graph``)."""
    obs_point = window.problem.obs_point
    while True:
        active = active & ~state.dropped_points[obs_point]
        last, state.last_graph = state.last_graph, None  # a retry builds its graph anew
        graph, values, point_rows, pose_rows, rows, equality = _build_graph(window, state, active, robust, config, last)
        if len(rows) == 0:
            return
        try:
            ordering = _landmarks_first(window, point_rows, pose_rows) if config.ordering == "landmarks_first" else None
            optimizer, result, initial_error = _optimize(graph, values, ordering, iterations, config)
        except RuntimeError as exc:
            if _repair(exc, window, state, config):
                continue
            return
        if math.isnan(state.initial_error):
            state.initial_error = initial_error
        state.final_error = float(optimizer.error())
        state.iterations += int(optimizer.iterations())
        state.passes += 1
        _read_back(result, window, state, point_rows, pose_rows[~window.problem.fixed[pose_rows]])
        if keep_graph:
            state.last_graph = _PassGraph(graph, result, rows, pose_rows, point_rows, equality, robust)
        return


def _optimize(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    ordering: gtsam.Ordering | None,
    iterations: int,
    config: LocalBAConfig,
):
    """Run gtsam's Levenberg-Marquardt on the graph; returns the optimiser (error, iterations), the
    result and the error it started from (which the optimiser computed when it was made)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setlambdaInitial(config.lambda_initial)
    params.setlambdaLowerBound(config.lambda_lower_bound)
    params.setMaxIterations(iterations)
    params.setRelativeErrorTol(config.relative_error_tolerance)
    params.setAbsoluteErrorTol(config.absolute_error_tolerance)
    params.setLinearSolverType(config.linear_solver.upper())
    if ordering is None:
        params.setOrderingType(config.ordering.upper())
    else:
        params.setOrdering(ordering)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    initial_error = float(optimizer.error())
    return optimizer, optimizer.optimize(), initial_error


def _landmarks_first(window: _Window, point_rows: np.ndarray, pose_rows: np.ndarray) -> gtsam.Ordering:
    """Landmarks (3x3 blocks, each touching a few poses: no fill-in), then free poses, then fixed ones.

    Fixed poses go last: their NonlinearEquality factor is a constrained (sigma 0) model, which
    makes gtsam eliminate every factor joined with it by QR instead of Cholesky, much slower when
    they come first (benchmarks/local_ba.md).
    """
    ordering = gtsam.Ordering()
    for key in window.point_keys[point_rows].tolist():
        ordering.push_back(key)
    fixed = window.problem.fixed[pose_rows]
    for k in np.concatenate([pose_rows[~fixed], pose_rows[fixed]]).tolist():
        ordering.push_back(window.pose_keys[k])
    return ordering


def _build_graph(
    window: _Window, state: _State, active: np.ndarray, robust: bool, config: LocalBAConfig, last: _PassGraph | None = None
):
    """The factor graph and initial values of one pass, its point rows (in key order), pose rows,
    observation rows (in factor order) and the fixed poses' equality factor indices. With ``last``
    (the previous pass's graph, on the same factors) holding every row of this pass, that graph
    less the other rows' factors, and its result less the variables left without a factor: the
    same factors in the same order (gtsam skips removed ones), at the same values."""
    p = window.problem
    rows = np.flatnonzero(active & constrained_points(window.problem, window.stereo, active)[p.obs_point])
    pose_rows = np.unique(p.obs_keyframe[rows])
    point_rows = np.unique(p.obs_point[rows])
    # extractPoint3 returns points in key order; keep the rows in that order to read them back.
    point_rows = point_rows[np.argsort(window.point_keys[point_rows], kind="stable")]
    if last is not None and last.robust == robust and np.isin(rows, last.rows).all():
        graph, values = last.graph, last.values
        for index in np.flatnonzero(~np.isin(last.rows, rows)).tolist():
            graph.remove(index)
        for k in np.setdiff1d(last.pose_rows, pose_rows).tolist():
            values.erase(window.pose_keys[k])
            if k in last.equality_index:
                graph.remove(last.equality_index[k])
        for key in window.point_keys[np.setdiff1d(last.point_rows, point_rows)].tolist():
            values.erase(key)
        kept = set(pose_rows.tolist())
        equality = {k: i for k, i in last.equality_index.items() if k in kept}
        return graph, values, point_rows, pose_rows, last.rows, equality
    built = state.factors[robust]
    _build_factors(window, state, rows[[r not in built for r in rows.tolist()]], robust, config)
    graph = gtsam.NonlinearFactorGraph()
    for r in rows.tolist():
        graph.add(built[r])
    values = gtsam.Values()
    pose_keys = window.pose_keys
    equality: dict[int, int] = {}
    for k in pose_rows.tolist():
        pose = gtsam.Pose3(state.T_world_cam[k])
        values.insert(pose_keys[k], pose)
        if p.fixed[k]:
            equality[k] = int(graph.size())
            graph.add(gtsam.NonlinearEqualityPose3(pose_keys[k], pose))
    for key, p_world in zip(window.point_keys[point_rows].tolist(), state.p_world[point_rows]):
        values.insert(key, p_world)  # a Point3 is a numpy (3,) array in gtsam's Python wrapper
    return graph, values, point_rows, pose_rows, rows, equality


def _build_factors(window: _Window, state: _State, rows: np.ndarray, robust: bool, config: LocalBAConfig) -> None:
    """Reprojection factors of observation ``rows`` into ``state.factors[robust]``; one noise model per distinct sigma."""
    if len(rows) == 0:
        return
    p = window.problem
    stereo = window.stereo[rows]
    # Observations sharing (1/sigma^2, dim, right-u scale, disparity sigma) share a noise model object.
    keys = np.column_stack([
        p.obs_inv_sigma2[rows], np.where(stereo, 3.0, 2.0),
        np.where(stereo, window.right_sigma_scale[rows], 1.0), np.where(stereo, window.disparity_sigma[rows], 0.0),
    ])  # fmt: skip
    # One integer code per row from per-column 1-D uniques: a tenth of np.unique(axis=0)'s cost.
    code = np.zeros(len(rows), dtype=np.int64)
    for column in keys.T:
        values, index = np.unique(column, return_inverse=True)
        code = code * len(values) + index.reshape(-1)
    _, first, which = np.unique(code, return_index=True, return_inverse=True)
    noise = _NoiseModels(robust, config)
    models = [noise.get(info, int(dim), scale, disparity) for info, dim, scale, disparity in keys[first].tolist()]
    which = which.reshape(-1).tolist()
    pose_keys, point_keys = window.pose_keys, window.point_keys.tolist()
    kf_list, pt_list = p.obs_keyframe[rows].tolist(), p.obs_point[rows].tolist()
    px, right_u = p.obs_px[rows].tolist(), p.obs_right_u[rows].tolist()
    cal_mono, cal_stereo = window.cal_mono, window.cal_stereo
    factors = state.factors[robust]
    for i, (row, is_stereo) in enumerate(zip(rows.tolist(), stereo.tolist())):
        u, v = px[i]
        x, l = pose_keys[kf_list[i]], point_keys[pt_list[i]]
        if is_stereo:
            factors[row] = gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(u, right_u[i], v), models[which[i]], x, l, cal_stereo)
        else:
            factors[row] = gtsam.GenericProjectionFactorCal3_S2(np.array((u, v)), models[which[i]], x, l, cal_mono)


class _NoiseModels:
    """Noise models with sigma = 1/sqrt(inv_sigma2) px, Huber-wrapped when robust; one per distinct key."""

    def __init__(self, robust: bool, config: LocalBAConfig) -> None:
        self._robust = robust
        self._huber = {2: config.huber_mono, 3: config.huber_stereo}
        self._cache: dict[tuple[float, int, float, float], gtsam.noiseModel.Base] = {}

    def get(
        self, inv_sigma2: float, dim: int, right_sigma_scale: float = 1.0, disparity_sigma: float = 0.0
    ) -> gtsam.noiseModel.Base:
        key = (inv_sigma2, dim, right_sigma_scale, disparity_sigma)
        model = self._cache.get(key)
        if model is None:
            sigma = 1.0 / math.sqrt(inv_sigma2)
            if dim == 3 and disparity_sigma > 0:
                # RGB-D's virtual right u = u - bf / depth carries the keypoint's error of u plus the
                # depth's: cov(uL, uR) = sigma^2, var(uR) = sigma^2 + disparity_sigma^2 (order uL, uR, v).
                s2, d2 = sigma * sigma, disparity_sigma * disparity_sigma
                model = gtsam.noiseModel.Gaussian.Covariance(np.array([[s2, s2, 0.0], [s2, s2 + d2, 0.0], [0.0, 0.0, s2]]))
            elif dim == 3 and right_sigma_scale != 1.0:  # StereoPoint2 order: uL, uR, v
                model = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma, sigma * right_sigma_scale, sigma]))
            else:
                model = gtsam.noiseModel.Isotropic.Sigma(dim, sigma)
            if self._robust:
                # Huber on the whitened residual norm: quadratic up to the chi2 threshold's root, linear beyond.
                model = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(self._huber[dim]), model)
            self._cache[key] = model
        return model


def _read_back(
    result: gtsam.Values, window: _Window, state: _State, point_rows: np.ndarray, free_pose_rows: np.ndarray
) -> None:
    """Copy the optimised points and free poses from gtsam into the state arrays."""
    if len(point_rows):
        state.p_world[point_rows] = gtsam.utilities.extractPoint3(result)
    for k in free_pose_rows.tolist():
        state.T_world_cam[k] = result.atPose3(window.pose_keys[k]).matrix()


def _repair(exc: RuntimeError, window: _Window, state: _State, config: LocalBAConfig) -> bool:
    """Drop the landmark gtsam names in ``exc`` and return True to retry; False (failure noted) otherwise."""
    state.retries += 1
    message = " ".join(str(exc).split())
    match = _NEAR_VARIABLE.search(message)
    row = window.point_row_of_key.get(int(match.group(1))) if match else None
    if row is not None and state.retries <= config.max_retries:
        state.dropped_points[row] = True
        logger.debug("local BA: dropped point %d after: %s", int(window.problem.point_ids[row]), message[:120])
        return True
    state.failure = message[:300]
    logger.warning("local BA stopped, keeping the estimate so far: %s", state.failure)
    return False
