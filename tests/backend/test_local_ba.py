"""Local bundle adjustment recovers known synthetic windows, flags outliers and survives bad geometry."""

import dataclasses

import gtsam
import numpy as np
import pytest

from zenslam.backend import local_ba
from zenslam.backend.gtsam_keys import landmark_key, pose_key
from zenslam.backend.local_ba import BAProblem, LocalBAConfig, LocalBundleAdjuster
from zenslam.backend.local_mapping import bundle_adjuster
from zenslam.camera import PinholeCalibration
from zenslam.errors import ZenslamError
from zenslam.geometry import invert_T, make_T, so3_exp, so3_log
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE
from zenslam.config import from_mapping

KITTI = PinholeCalibration(707.0912, 707.0912, 601.8873, 183.1104, 1226, 370, baseline_m=0.5372)


def make_window(seed, n_keyframes=5, n_points=300, n_fixed=2, stereo=True, noise_px=0.5, outlier_fraction=0.0):
    """A room-scale window: keyframes 0.4 m apart sideways, points 3-9 m ahead seen where they project.

    Returns the problem with perturbed initial poses (5 cm, 1 deg; fixed ones exact) and points
    (5 cm), the true poses and points, and the mask of gross outlier observations.
    """
    rng = np.random.default_rng(seed)
    c = KITTI
    T_true = np.stack([make_T(so3_exp([0.0, -0.02 * k, 0.0]), [0.4 * k, 0.0, 0.1 * k]) for k in range(n_keyframes)])
    centre = T_true[n_keyframes // 2]
    u, v = rng.uniform(0, c.width, n_points), rng.uniform(0, c.height, n_points)
    z = rng.uniform(3.0, 9.0, n_points)
    p_true = np.stack([(u - c.cx) * z / c.fx, (v - c.cy) * z / c.fy, z], 1) @ centre[:3, :3].T + centre[:3, 3]
    obs_kf, obs_pt = np.meshgrid(np.arange(n_keyframes), np.arange(n_points), indexing="ij")
    obs_kf, obs_pt = obs_kf.ravel(), obs_pt.ravel()
    p_cam = np.einsum("nji,nj->ni", T_true[obs_kf, :3, :3], p_true[obs_pt] - T_true[obs_kf, :3, 3])
    px = np.stack([c.fx * p_cam[:, 0] / p_cam[:, 2] + c.cx, c.fy * p_cam[:, 1] / p_cam[:, 2] + c.cy], 1)
    seen = (p_cam[:, 2] > 0.5) & (px >= 0).all(axis=1) & (px[:, 0] < c.width) & (px[:, 1] < c.height)
    obs_kf, obs_pt, p_cam, px = obs_kf[seen], obs_pt[seen], p_cam[seen], px[seen]
    right_u = px[:, 0] - c.bf / p_cam[:, 2]
    n_obs = len(obs_kf)
    obs_px = px + rng.normal(scale=noise_px, size=(n_obs, 2))
    obs_right_u = right_u + rng.normal(scale=noise_px, size=n_obs) if stereo else np.full(n_obs, np.nan)
    outlier = rng.random(n_obs) < outlier_fraction
    obs_px[outlier] += rng.uniform(15.0, 60.0, (int(outlier.sum()), 2)) * rng.choice([-1.0, 1.0], (int(outlier.sum()), 2))
    fixed = np.arange(n_keyframes) < n_fixed
    T_init = T_true.copy()
    for k in np.flatnonzero(~fixed):
        axis, direction = rng.normal(size=3), rng.normal(size=3)
        delta = make_T(so3_exp(np.deg2rad(1.0) * axis / np.linalg.norm(axis)), 0.05 * direction / np.linalg.norm(direction))
        T_init[k] = T_true[k] @ delta
    offsets = rng.normal(size=(n_points, 3))
    p_init = p_true + 0.05 * offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    problem = BAProblem(
        calibration=c,
        keyframe_ids=np.arange(10, 10 + n_keyframes, dtype=np.int64),
        T_world_cam=T_init,
        fixed=fixed,
        point_ids=np.arange(n_points, dtype=np.int64) * 7 + 3,
        p_world=p_init,
        obs_keyframe=obs_kf,
        obs_point=obs_pt,
        obs_px=obs_px,
        obs_right_u=obs_right_u,
        obs_inv_sigma2=1.2 ** (-2.0 * rng.integers(0, 3, n_obs)),
    )
    return problem, T_true, p_true, outlier


ROOM = PinholeCalibration(460.0, 460.0, 319.5, 239.5, 640, 480, baseline_m=0.1)  # synthetic room camera, virtual baseline
DEPTH_SIGMA_AT_1M = 0.0015  # m / m^2: the backend's default RGB-D depth noise model


def make_rgbd_window(seed, n_keyframes=6, n_points=400, n_fixed=2):
    """An RGB-D window: keyframes 8 cm apart turning 1.7 deg, points 3-5 m ahead, keypoints at levels 0-7
    with sigma 1.2**level px, depth with sigma 1.5 mm * z^2 and right u = u - bf / depth (so u and
    right u share the keypoint's error). Returns the problem (initial poses 2 cm / 0.3 deg off, points
    3 cm off, fixed poses exact), the true poses and the true points."""
    rng = np.random.default_rng(seed)
    c = ROOM
    T_true = np.stack([make_T(so3_exp([0.0, 0.03 * k, 0.0]), [0.08 * k, 0.0, 0.02 * k]) for k in range(n_keyframes)])
    centre = T_true[n_keyframes // 2]
    u, v, z = rng.uniform(0, c.width, n_points), rng.uniform(0, c.height, n_points), rng.uniform(3.0, 5.0, n_points)
    p_true = np.stack([(u - c.cx) * z / c.fx, (v - c.cy) * z / c.fy, z], 1) @ centre[:3, :3].T + centre[:3, 3]
    obs_kf, obs_pt = (a.ravel() for a in np.meshgrid(np.arange(n_keyframes), np.arange(n_points), indexing="ij"))
    p_cam = np.einsum("nji,nj->ni", T_true[obs_kf, :3, :3], p_true[obs_pt] - T_true[obs_kf, :3, 3])
    px = np.stack([c.fx * p_cam[:, 0] / p_cam[:, 2] + c.cx, c.fy * p_cam[:, 1] / p_cam[:, 2] + c.cy], 1)
    seen = (px >= 0).all(axis=1) & (px[:, 0] < c.width) & (px[:, 1] < c.height)
    obs_kf, obs_pt, p_cam, px = obs_kf[seen], obs_pt[seen], p_cam[seen], px[seen]
    level = rng.integers(0, 8, len(obs_kf))
    obs_px = px + rng.normal(size=(len(obs_kf), 2)) * 1.2 ** level[:, None]
    depth = p_cam[:, 2] + DEPTH_SIGMA_AT_1M * p_cam[:, 2] ** 2 * rng.normal(size=len(obs_kf))
    fixed = np.arange(n_keyframes) < n_fixed
    T_init = T_true.copy()
    for k in np.flatnonzero(~fixed):
        T_init[k] = T_true[k] @ make_T(so3_exp(rng.normal(scale=0.005, size=3)), rng.normal(scale=0.02, size=3))
    problem = BAProblem(
        calibration=c, keyframe_ids=np.arange(n_keyframes), T_world_cam=T_init, fixed=fixed,
        point_ids=np.arange(n_points), p_world=p_true + rng.normal(scale=0.03, size=(n_points, 3)),
        obs_keyframe=obs_kf, obs_point=obs_pt, obs_px=obs_px, obs_right_u=obs_px[:, 0] - c.bf / depth,
        obs_inv_sigma2=1.2 ** (-2.0 * level),
    )  # fmt: skip
    return problem, T_true, p_true


def pose_errors(T_est, T_true):
    """Camera position error (m) and rotation error (deg) per keyframe."""
    position = np.linalg.norm(T_est[:, :3, 3] - T_true[:, :3, 3], axis=1)
    rotation = np.array([np.rad2deg(np.linalg.norm(so3_log(a[:3, :3].T @ b[:3, :3]))) for a, b in zip(T_est, T_true)])
    return position, rotation


def run(problem, method="batch_lm", **overrides):
    return bundle_adjuster(LocalBAConfig(method=method, **overrides)).optimize(problem)


@pytest.fixture(params=["schur_lm", "batch_lm"])
def method(request):
    """Both solvers: numpy's reduced camera system and gtsam's factor graph solve the same problem."""
    return request.param


@pytest.mark.parametrize("seed", [0, 1])
def test_stereo_window_recovers_poses_and_points_with_fixed_poses_exact(seed, method):
    problem, T_true, p_true, _ = make_window(seed)
    result = run(problem, method)
    position, rotation = pose_errors(result.T_world_cam, T_true)
    assert position.max() < 0.01  # metres
    assert rotation.max() < 0.1  # degrees
    assert np.median(np.linalg.norm(result.p_world - p_true, axis=1)) < 0.02
    np.testing.assert_array_equal(result.T_world_cam[:2], problem.T_world_cam[:2])
    assert result.inlier_obs.mean() > 0.97  # 0.5 px noise: almost nothing exceeds the 95% chi2 at sigma >= 1 px
    assert len(result.removed_point_ids) == 0
    assert result.stats["final_error"] < result.stats["initial_error"]
    assert 0 < result.stats["iterations"] <= 15
    assert result.stats["failure"] is None


def test_gross_outliers_are_flagged_and_the_solution_stays_accurate(method):
    problem, T_true, p_true, outlier = make_window(3, outlier_fraction=0.1)
    result = run(problem, method)
    assert (~result.inlier_obs[outlier]).mean() > 0.9  # recall of outliers
    assert result.inlier_obs[~outlier].mean() > 0.95
    position, rotation = pose_errors(result.T_world_cam, T_true)
    assert position.max() < 0.01 and rotation.max() < 0.1
    assert np.median(np.linalg.norm(result.p_world - p_true, axis=1)) < 0.02
    assert result.stats["n_outliers"] == int((~result.inlier_obs).sum())


def test_mono_window_with_three_fixed_keyframes(method):
    problem, T_true, p_true, _ = make_window(4, n_keyframes=6, n_fixed=3, stereo=False)
    result = run(problem, method)
    position, rotation = pose_errors(result.T_world_cam, T_true)
    assert position.max() < 0.01 and rotation.max() < 0.1
    assert np.median(np.linalg.norm(result.p_world - p_true, axis=1)) < 0.02  # depth from the 2 m of motion
    np.testing.assert_array_equal(result.T_world_cam[:3], problem.T_world_cam[:3])


def test_point_behind_the_cameras_is_flagged_and_removed(method):
    problem, T_true, _, _ = make_window(5)
    p_world = problem.p_world.copy()
    p_world[7] = [0.5, 0.2, -10.0]  # behind every keyframe
    result = run(dataclasses.replace(problem, p_world=p_world), method)
    assert not result.inlier_obs[problem.obs_point == 7].any()
    assert problem.point_ids[7] in result.removed_point_ids
    assert pose_errors(result.T_world_cam, T_true)[0].max() < 0.01


def test_non_finite_point_is_removed_and_empty_or_all_fixed_windows_run(method):
    problem, T_true, _, _ = make_window(11)
    p_world = problem.p_world.copy()
    p_world[8] = np.nan
    result = run(dataclasses.replace(problem, p_world=p_world), method)
    assert problem.point_ids[8] in result.removed_point_ids
    assert pose_errors(result.T_world_cam, T_true)[0].max() < 0.01
    all_fixed = run(dataclasses.replace(problem, fixed=np.ones(5, dtype=bool)), method)
    np.testing.assert_array_equal(all_fixed.T_world_cam, problem.T_world_cam)
    empty = dataclasses.replace(
        problem, obs_keyframe=[], obs_point=[], obs_px=np.zeros((0, 2)), obs_right_u=[], obs_inv_sigma2=[]
    )
    result = run(empty, method)
    np.testing.assert_array_equal(result.T_world_cam, problem.T_world_cam)
    assert len(result.removed_point_ids) == len(problem.point_ids)  # no observation, no inlier


def test_single_monocular_observation_is_held_and_does_not_crash(method):
    problem, T_true, p_true, _ = make_window(6)
    keep = (problem.obs_point != 9) | (problem.obs_keyframe == 4)
    right_u = problem.obs_right_u.copy()
    right_u[problem.obs_point == 9] = np.nan
    lone = dataclasses.replace(
        problem,
        obs_keyframe=problem.obs_keyframe[keep],
        obs_point=problem.obs_point[keep],
        obs_px=problem.obs_px[keep],
        obs_right_u=right_u[keep],
        obs_inv_sigma2=problem.obs_inv_sigma2[keep],
    )
    result = run(lone, method)
    np.testing.assert_array_equal(result.p_world[9], problem.p_world[9])  # no depth from one ray: held
    assert pose_errors(result.T_world_cam, T_true)[0].max() < 0.01
    assert result.stats["failure"] is None


def test_gtsam_indeterminant_message_names_the_key_the_repair_parses():
    # Gauss-Newton (no damping) on a point seen by one ray: gtsam's own message, whatever its wording
    # around the key, must keep "near variable <key>" for the repair to find the landmark.
    calibration = gtsam.Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(pose_key(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    graph.add(gtsam.GenericProjectionFactorCal3_S2(np.array([330.0, 245.0]), noise, pose_key(0), landmark_key(42), calibration))
    values = gtsam.Values()
    values.insert(pose_key(0), gtsam.Pose3())
    values.insert(landmark_key(42), gtsam.Point3(0.0, 0.0, 5.0))
    with pytest.raises(RuntimeError) as info:
        gtsam.GaussNewtonOptimizer(graph, values).optimize()
    match = local_ba._NEAR_VARIABLE.search(" ".join(str(info.value).split()))
    assert match and int(match.group(1)) == landmark_key(42)


def failing_once(monkeypatch, key):
    """Make the first gtsam solve raise IndeterminantLinearSystemException's message naming ``key``."""
    real = local_ba._optimize
    calls = []

    def optimize(*args):
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError(f"Indeterminate linear system detected while working near variable\n{key} (Symbol: ?).")
        return real(*args)

    monkeypatch.setattr(local_ba, "_optimize", optimize)
    return calls


def test_landmark_named_by_gtsam_is_dropped_and_the_pass_retried(monkeypatch):
    problem, T_true, _, _ = make_window(7)
    calls = failing_once(monkeypatch, landmark_key(problem.point_ids[11]))
    result = run(problem)
    assert len(calls) == 3 and result.stats["passes"] == 2  # failed robust pass, its retry, the refinement pass
    assert result.stats["retries"] == 1 and result.stats["n_dropped_points"] == 1
    assert problem.point_ids[11] in result.removed_point_ids
    assert not result.inlier_obs[problem.obs_point == 11].any()
    np.testing.assert_array_equal(result.p_world[11], problem.p_world[11])
    assert pose_errors(result.T_world_cam, T_true)[0].max() < 0.01
    assert result.stats["failure"] is None


def test_failure_near_a_pose_returns_the_estimate_so_far_without_raising(monkeypatch):
    problem, _, _, _ = make_window(7)
    failing_once(monkeypatch, pose_key(problem.keyframe_ids[3]))
    result = run(problem)
    assert "near variable" in result.stats["failure"]
    np.testing.assert_array_equal(result.T_world_cam, problem.T_world_cam)  # nothing ran
    assert result.inlier_obs.shape == problem.obs_point.shape


def test_same_input_gives_identical_output_bytes(method):
    problem, _, _, _ = make_window(8, outlier_fraction=0.05)
    a, b = run(problem, method), run(problem, method)
    assert a.T_world_cam.tobytes() == b.T_world_cam.tobytes()
    assert a.p_world.tobytes() == b.p_world.tobytes()
    assert a.inlier_obs.tobytes() == b.inlier_obs.tobytes()
    assert a.removed_point_ids.tobytes() == b.removed_point_ids.tobytes()


def test_backend_point_ids_above_2_62_work(method):
    problem, T_true, p_true, _ = make_window(9)
    ids = problem.point_ids.copy()
    ids[::2] += BACKEND_POINT_ID_BASE
    result = run(dataclasses.replace(problem, point_ids=ids), method)
    assert pose_errors(result.T_world_cam, T_true)[0].max() < 0.01
    assert np.median(np.linalg.norm(result.p_world - p_true, axis=1)) < 0.02


def test_inconsistent_problem_raises_naming_the_array():
    problem, _, _, _ = make_window(10)
    with pytest.raises(ZenslamError, match="obs_px has shape"):
        dataclasses.replace(problem, obs_px=problem.obs_px[:-1])
    with pytest.raises(ZenslamError, match="obs_point must index"):
        dataclasses.replace(problem, obs_point=problem.obs_point + 1)


def test_config_builds_from_yaml_mapping():
    config = from_mapping(LocalBAConfig, {"linear_solver": "multifrontal_cholesky", "refine_iterations": 3})
    assert config.linear_solver == "multifrontal_cholesky" and config.refine_iterations == 3
    assert config.huber_mono == pytest.approx(5.991**0.5)


def test_both_passes_run_and_outliers_are_dropped(method):
    problem, T_true, _, outlier = make_window(10, outlier_fraction=0.05)
    result = run(problem, method)
    assert result.stats["passes"] == 2 and not result.inlier_obs[outlier].any()
    assert pose_errors(result.T_world_cam, T_true)[0].max() < 0.01


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rgbd_depth_keeps_points_and_poses_where_the_sensor_puts_them(seed, method):
    # ORB-SLAM's model (right u independent, the keypoint's sigma) leaves a 3-5 m point's depth to
    # the parallax between keyframes: median point error ~13 cm, poses 1-2 cm. Modelled as u minus
    # a disparity of the depth sensor's sigma, the depth holds the points to ~1 cm.
    problem, T_true, p_true = make_rgbd_window(seed)
    sigma = np.full(len(problem.obs_px), ROOM.bf * DEPTH_SIGMA_AT_1M)
    result = run(dataclasses.replace(problem, obs_disparity_sigma=sigma), method)
    assert np.median(np.linalg.norm(result.p_world - p_true, axis=1)) < 0.02  # metres
    assert pose_errors(result.T_world_cam, T_true)[0].max() < 0.012  # metres
    assert result.inlier_obs.mean() > 0.95
    orb_slam = run(problem, method)
    assert np.median(np.linalg.norm(orb_slam.p_world - p_true, axis=1)) > 0.05


def test_rgbd_chi2_is_the_factors_whitened_error():
    problem, _, _ = make_rgbd_window(3, n_points=60)
    sigma = np.where(np.arange(len(problem.obs_px)) % 2 == 0, 0.07, 0.0)  # RGB-D and stereo rows side by side
    problem = dataclasses.replace(problem, obs_disparity_sigma=sigma)
    config = LocalBAConfig()
    window = local_ba._Window.of(problem, config)
    state = local_ba._State(problem.T_world_cam.copy(), problem.p_world.copy())
    chi2, _ = window.chi2(state)
    rows = np.arange(len(problem.obs_px))
    local_ba._build_factors(window, state, rows, False, config)
    values = gtsam.Values()
    for k, T in enumerate(problem.T_world_cam):
        values.insert(pose_key(int(problem.keyframe_ids[k])), gtsam.Pose3(T))
    for j, p in enumerate(problem.p_world):
        values.insert(landmark_key(int(problem.point_ids[j])), p)
    factor_chi2 = np.array([2.0 * state.factors[False][r].error(values) for r in rows.tolist()])
    np.testing.assert_allclose(chi2, factor_chi2, rtol=1e-6)


def test_a_one_step_refinement_on_the_robust_passs_huber_factors_takes_the_kernel_free_step(monkeypatch):
    """The refinement reuses the Huber factors: at its start every inlier is within Huber's threshold,
    so they linearize as kernel-free factors would, and give the same step."""
    problem, _, _, outlier = make_window(10, outlier_fraction=0.05)
    reused = run(problem)
    inner, kernels = local_ba._run_pass, []

    def kernel_free_refinement(window, state, active, robust, iterations, config, keep_graph=False):
        kernels.append(robust)
        inner(window, state, active, robust and len(kernels) == 1, iterations, config, keep_graph)

    monkeypatch.setattr(local_ba, "_run_pass", kernel_free_refinement)
    rebuilt = run(problem)
    assert kernels == [True, True]  # the refinement was handed the Huber factors
    assert reused.stats["passes"] == 2 and not reused.inlier_obs[outlier].any()
    np.testing.assert_allclose(reused.T_world_cam, rebuilt.T_world_cam, rtol=0, atol=1e-9)
    np.testing.assert_allclose(reused.p_world, rebuilt.p_world, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(reused.inlier_obs, rebuilt.inlier_obs)


def test_the_refinement_on_the_robust_passs_graph_less_its_outliers_is_the_refinement_on_a_graph_built_anew(monkeypatch):
    """The one-step refinement takes the robust pass's graph and result, less the outliers' factors and
    the points left without one, instead of a graph and values built anew: the same factors in the
    same order at the same values, so the same result bit for bit."""
    problem, _, _, outlier = make_window(10, outlier_fraction=0.05)
    removed = []
    remove = gtsam.NonlinearFactorGraph.remove

    class Counting(gtsam.NonlinearFactorGraph):
        def remove(self, index):
            removed.append(index)
            remove(self, index)

    monkeypatch.setattr(local_ba.gtsam, "NonlinearFactorGraph", Counting)
    shrunk = run(problem)
    assert removed and shrunk.stats["passes"] == 2 and not shrunk.inlier_obs[outlier].any()
    inner = local_ba._run_pass
    monkeypatch.setattr(local_ba, "_run_pass", lambda *args: inner(*args[:6], keep_graph=False))
    removed.clear()
    rebuilt = run(problem)
    assert not removed  # built anew
    np.testing.assert_array_equal(shrunk.T_world_cam, rebuilt.T_world_cam)
    np.testing.assert_array_equal(shrunk.p_world, rebuilt.p_world)
    np.testing.assert_array_equal(shrunk.inlier_obs, rebuilt.inlier_obs)
    assert shrunk.stats["final_error"] == rebuilt.stats["final_error"]


def test_first_pass_graph_is_the_robust_pass_the_adjuster_starts_from():
    """One Huber-wrapped factor per usable observation, an equality per fixed pose, every key
    valued, landmarks ordered before poses; one linear solve of it is LM's first step."""
    problem, _, _, _ = make_window(3, n_keyframes=4, n_points=60)
    graph, values, ordering = local_ba.first_pass_graph(problem, LocalBAConfig())
    n_fixed = int(problem.fixed.sum())
    assert graph.size() == len(problem.obs_point) + n_fixed
    keys = [ordering.at(i) for i in range(ordering.size())]
    landmarks = {landmark_key(int(p)) for p in problem.point_ids}
    assert set(keys) == set(values.keys()) == landmarks | {pose_key(int(k)) for k in problem.keyframe_ids}
    assert set(keys[: len(landmarks)]) == landmarks  # then the free poses, the fixed ones last
    assert keys[-n_fixed:] == [pose_key(int(k)) for k in problem.keyframe_ids[problem.fixed]]
    robust = [graph.at(i).noiseModel() for i in range(len(problem.obs_point))]
    assert all(isinstance(m, gtsam.noiseModel.Robust) for m in robust)
    step = graph.linearize(values).optimize(ordering)
    assert np.isfinite(step.vector()).all() and np.linalg.norm(step.vector()) > 0


def _windows_of_every_kind():
    """Stereo with outliers, monocular, RGB-D with its depth model, far stereo rows with a weaker right u."""
    stereo, _, _, _ = make_window(12, n_keyframes=7, outlier_fraction=0.05)
    mono, _, _, _ = make_window(13, n_keyframes=6, n_fixed=3, stereo=False, outlier_fraction=0.05)
    rgbd, _, _ = make_rgbd_window(14)
    rgbd = dataclasses.replace(rgbd, obs_disparity_sigma=np.full(len(rgbd.obs_px), ROOM.bf * DEPTH_SIGMA_AT_1M))
    scaled = dataclasses.replace(stereo, obs_right_sigma_scale=np.where(np.arange(len(stereo.obs_px)) % 3 == 0, 2.5, 1.0))
    mixed_right_u = stereo.obs_right_u.copy()
    mixed_right_u[::4] = np.nan  # a quarter of the rows monocular
    mixed = dataclasses.replace(stereo, obs_right_u=mixed_right_u)
    # A point seen twice by one keyframe (two keypoints, 0.3 px apart): both rows weigh on the pose.
    twice = np.arange(0, len(stereo.obs_px), 7)
    seen_twice = dataclasses.replace(
        stereo,
        obs_keyframe=np.concatenate([stereo.obs_keyframe, stereo.obs_keyframe[twice]]),
        obs_point=np.concatenate([stereo.obs_point, stereo.obs_point[twice]]),
        obs_px=np.concatenate([stereo.obs_px, stereo.obs_px[twice] + 0.3]),
        obs_right_u=np.concatenate([stereo.obs_right_u, stereo.obs_right_u[twice] + 0.3]),
        obs_inv_sigma2=np.concatenate([stereo.obs_inv_sigma2, stereo.obs_inv_sigma2[twice]]),
    )
    return {
        "stereo": stereo, "mono": mono, "rgbd": rgbd, "scaled_right_u": scaled, "stereo_and_mono": mixed,
        "point_seen_twice": seen_twice,
    }  # fmt: skip


@pytest.mark.parametrize("kind", ["stereo", "mono", "rgbd", "scaled_right_u", "stereo_and_mono", "point_seen_twice"])
def test_the_reduced_system_takes_gtsams_steps_to_the_same_optimum(kind):
    # The same problem, damping, acceptance and stopping rules: the same iterations and errors, and
    # an estimate that differs only by rounding (and so the same classification of every observation).
    problem = _windows_of_every_kind()[kind]
    gtsam_result, schur_result = run(problem, "batch_lm"), run(problem, "schur_lm")
    assert schur_result.stats["iterations"] == gtsam_result.stats["iterations"]
    assert schur_result.stats["final_error"] == pytest.approx(gtsam_result.stats["final_error"], rel=1e-9)
    assert schur_result.stats["initial_error"] == pytest.approx(gtsam_result.stats["initial_error"], rel=1e-12)
    np.testing.assert_allclose(schur_result.T_world_cam, gtsam_result.T_world_cam, atol=1e-9)
    np.testing.assert_allclose(schur_result.p_world, gtsam_result.p_world, atol=1e-8)
    np.testing.assert_array_equal(schur_result.inlier_obs, gtsam_result.inlier_obs)
    np.testing.assert_array_equal(schur_result.removed_point_ids, gtsam_result.removed_point_ids)
    assert gtsam_result.stats["n_outliers"] > 0 or kind == "rgbd"


def test_the_warm_up_compiles_the_schur_kernels_for_the_types_local_ba_uses():
    # The backend loads them at its start; its first local BA must find nothing left to compile.
    from zenslam.backend import ba_normal_equations, schur_complement
    from zenslam.backend.schur_ba import load_compiled_kernels

    load_compiled_kernels()
    kernels = (ba_normal_equations._project, ba_normal_equations._blocks, schur_complement._reduced_system,
               schur_complement._back_substitute)  # fmt: skip
    compiled = [len(k.signatures) for k in kernels]
    assert all(compiled)
    for kind, problem in _windows_of_every_kind().items():
        frozen = dataclasses.replace(problem, T_world_cam=problem.T_world_cam.copy(), p_world=problem.p_world.copy())
        frozen.T_world_cam.setflags(write=False)  # arrays from a message are read-only
        frozen.p_world.setflags(write=False)
        run(frozen, "schur_lm")
        assert [len(k.signatures) for k in kernels] == compiled, kind
