"""Global BA over a whole map: built from copies, recovers a perturbed map, and its result is applied with
keyframes and points added meanwhile corrected through the spanning tree and their reference keyframe."""

import pickle

import numpy as np
import pytest

from zenslam.backend.ba_problem import BAResult
from zenslam.backend.global_ba import GlobalBAConfig, apply_global_ba, global_ba_problem, run_global_ba
from zenslam.backend.local_mapping import BAWindowConfig
from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.camera import PinholeCalibration
from zenslam.geometry import invert_T, make_T, so3_exp, so3_log, transform_points

CAL = PinholeCalibration(460.0, 460.0, 320.0, 240.0, 640, 480, baseline_m=0.1)


def make_keyframe(kf_id, T_world_cam, p_world_by_id, rng, noise_px=0.5):
    """A stereo keyframe whose keypoints are the (noisy) projections of the points it sees, associated to
    them, plus one last keypoint observing nothing yet."""
    ids = np.array(sorted(p_world_by_id), dtype=np.int64)
    p = np.array([p_world_by_id[i] for i in ids]).reshape(-1, 3)
    p_cam = transform_points(invert_T(T_world_cam), p)
    z = p_cam[:, 2]
    u, v = CAL.fx * p_cam[:, 0] / z + CAL.cx, CAL.fy * p_cam[:, 1] / z + CAL.cy
    seen = (z > 0.5) & (u >= 0) & (u < CAL.width) & (v >= 0) & (v < CAL.height)
    n = int(seen.sum())
    px = np.column_stack([u[seen], v[seen]]) + rng.normal(scale=noise_px, size=(n, 2))
    right_u = px[:, 0] - CAL.bf / z[seen] + rng.normal(scale=noise_px, size=n)
    return BackendKeyframe(
        id=kf_id, stamp_ns=kf_id, T_world_cam=T_world_cam.copy(), calibration=CAL, sensor="stereo",
        keypoints_px=np.vstack([px, [[CAL.cx, CAL.cy]]]), levels=np.zeros(n + 1, np.int64), angles_deg=np.zeros(n + 1),
        right_u=np.append(right_u, -1.0), depth_m=np.append(z[seen], -1.0), descriptors=np.zeros((n + 1, 32), np.uint8),
        scale_factors=1.2 ** np.arange(8), map_point_ids=np.append(ids[seen], -1),
    )  # fmt: skip


def true_scene(n_keyframes=6, n_points=150, seed=0):
    rng = np.random.default_rng(seed)
    poses = [make_T(so3_exp([0.0, 0.03 * k, 0.0]), [0.4 * k, 0.0, 0.0]) for k in range(n_keyframes)]
    points = np.column_stack([rng.uniform(-2.0, 4.0, n_points), rng.uniform(-1.5, 1.5, n_points), rng.uniform(3.0, 8.0, n_points)])
    return poses, points, rng


def perturbed_map(n_keyframes=6, n_points=150, seed=0):
    """The map built from noisy observations of the true scene, every pose but the first 3 cm / 0.5 deg
    off and every point 5 cm off; returns the map and the true poses and points."""
    poses, points, rng = true_scene(n_keyframes, n_points, seed)
    bmap = BackendMap()
    truth = {i: points[i] for i in range(n_points)}
    for i in range(n_points):
        bmap.add_point(i, points[i] + rng.normal(scale=0.05 / np.sqrt(3), size=3), 0)
    for k, T in enumerate(poses):
        kf = make_keyframe(k, T, truth, rng)
        if k > 0:
            kf.T_world_cam = T @ make_T(so3_exp(rng.normal(scale=np.radians(0.5) / np.sqrt(3), size=3)), rng.normal(scale=0.03 / np.sqrt(3), size=3))
        bmap.add_keyframe(kf)
    bmap.remove_weak_points(list(bmap.points), 1)
    bmap.take_changes()
    return bmap, poses, points


def errors(bmap, poses, points):
    pos = max(np.linalg.norm(bmap.keyframes[k].T_world_cam[:3, 3] - poses[k][:3, 3]) for k in bmap.keyframes)
    rot = max(np.linalg.norm(so3_log(bmap.keyframes[k].T_world_cam[:3, :3].T @ poses[k][:3, :3])) for k in bmap.keyframes)
    pts = np.median([np.linalg.norm(pt.p_world - points[i]) for i, pt in bmap.points.items()])
    return pos, np.degrees(rot), pts


def test_global_ba_recovers_a_perturbed_map():
    bmap, poses, points = perturbed_map()
    pos0, rot0, pts0 = errors(bmap, poses, points)
    problem = global_ba_problem(bmap, BAWindowConfig())
    assert problem.problem.fixed.tolist() == [True] + [False] * 5  # the first keyframe is the gauge
    assert len(problem.problem.point_ids) == len(bmap.points)
    result = run_global_ba(problem, GlobalBAConfig())
    counts = apply_global_ba(bmap, problem, result)
    assert counts == {"keyframes_optimised": 6, "keyframes_propagated": 0, "points_optimised": len(bmap.points), "points_propagated": 0}
    pos, rot, pts = errors(bmap, poses, points)
    assert pos < pos0 / 3 and rot < rot0 / 3 and pts < pts0 / 1.5
    assert np.array_equal(bmap.keyframes[0].T_world_cam, poses[0])
    assert bmap.check_consistency() == []
    # the optimum of the noisy observations: the same as reached from the true map
    for k, kf in bmap.keyframes.items():
        kf.T_world_cam = poses[k].copy()
    bmap.set_point_positions(list(bmap.points), np.array([points[i] for i in bmap.points]))
    from_truth = run_global_ba(global_ba_problem(bmap, BAWindowConfig()), GlobalBAConfig())
    assert result.stats["final_error"] == pytest.approx(from_truth.stats["final_error"], rel=1e-6)


def test_problem_is_a_snapshot_that_pickles():
    bmap, _, _ = perturbed_map(n_keyframes=3, n_points=40)
    problem = global_ba_problem(bmap, BAWindowConfig())
    p = problem.problem
    kf, pt = bmap.keyframes[1], bmap.points[int(p.point_ids[0])]
    for array in (p.T_world_cam, p.p_world, p.obs_px, p.obs_right_u):
        assert not any(np.shares_memory(array, a) for a in (kf.T_world_cam, kf.keypoints_px, kf.right_u, pt.p_world))
    before = (p.T_world_cam.copy(), p.p_world.copy(), p.obs_px.copy())
    bmap.set_keyframe_pose(1, np.eye(4))  # the map keeps changing while the problem is optimised
    bmap.set_point_position(int(p.point_ids[0]), [9.0, 9.0, 9.0])
    kf.keypoints_px[:] = 0.0
    assert all(np.array_equal(a, b) for a, b in zip(before, (p.T_world_cam, p.p_world, p.obs_px)))
    copy = pickle.loads(pickle.dumps(problem))  # so it can be optimised in another process
    assert np.array_equal(copy.problem.obs_px, p.obs_px) and copy.problem.calibration == p.calibration


def test_global_ba_problem_needs_two_keyframes():
    bmap = BackendMap()
    poses, points, rng = true_scene(1, 20)
    bmap.add_keyframe(make_keyframe(0, poses[0], {}, rng))
    assert global_ba_problem(bmap, BAWindowConfig()) is None


def test_apply_corrects_what_was_added_meanwhile_through_the_spanning_tree():
    bmap, poses, points = perturbed_map(n_keyframes=4, n_points=80)
    problem = global_ba_problem(bmap, BAWindowConfig())
    p = problem.problem
    # The "optimised" result: every pose and point moved by one rigid correction G (known answer).
    G = make_T(so3_exp([0.01, -0.02, 0.03]), [0.1, -0.05, 0.2])
    result = BAResult(G @ p.T_world_cam, transform_points(G, p.p_world), np.ones(len(p.obs_keyframe), bool), np.zeros(0, np.int64))
    # Meanwhile local mapping added keyframe 4 (below keyframe 3) and point 1000 created by it, moved a
    # point the BA had, and culled another.
    rng = np.random.default_rng(5)
    visible = {i: points[i] for i in range(0, 80, 2) if i in bmap.points}
    new_kf = make_keyframe(4, make_T(so3_exp([0.0, 0.1, 0.0]), [1.7, 0.0, 0.1]), visible, rng)
    bmap.add_keyframe(new_kf)
    parent = bmap.spanning_tree.parent(4)
    bmap.add_point(1000, [1.0, 0.5, 6.0], 4)
    bmap.add_observation(1000, 4, new_kf.n_keypoints - 1)
    culled = int(p.point_ids[3])
    bmap.remove_point(culled)
    T4_before = bmap.keyframes[4].T_world_cam.copy()
    parent_before = bmap.keyframes[parent].T_world_cam.copy()
    p1000_before = bmap.points[1000].p_world.copy()
    counts = apply_global_ba(bmap, problem, result)
    assert counts["keyframes_optimised"] == 4 and counts["keyframes_propagated"] == 1
    assert counts["points_propagated"] == 1 and counts["points_optimised"] == len(p.point_ids) - 1
    # the child took its parent's correction: parent_new parent_before^-1 T4_before
    expected = (G @ p.T_world_cam[list(p.keyframe_ids).index(parent)]) @ invert_T(parent_before) @ T4_before
    assert np.allclose(bmap.keyframes[4].T_world_cam, expected, atol=1e-12)
    correction4 = expected @ invert_T(T4_before)
    assert np.allclose(bmap.points[1000].p_world, transform_points(correction4, p1000_before[None])[0], atol=1e-12)
    row = 5
    assert np.allclose(bmap.points[int(p.point_ids[row])].p_world, transform_points(G, p.p_world[row : row + 1])[0])
    assert culled not in bmap.points
    assert bmap.check_consistency() == []


def test_global_ba_config_schedules():
    assert GlobalBAConfig().local_ba_config().robust_iterations == 5
    plain = GlobalBAConfig(robust_iterations=0, iterations=10).local_ba_config()
    assert plain.robust_iterations == 0 and plain.refine_iterations == 10 and plain.two_passes


def test_auto_solves_maps_up_to_the_dense_limit_by_the_schur_complement_and_larger_ones_by_gtsam():
    config = GlobalBAConfig(dense_max_keyframes=300)
    assert [config.local_ba_config(n).method for n in (2, 300, 301, 2000)] == ["schur_lm", "schur_lm", "batch_lm", "batch_lm"]
    assert GlobalBAConfig(solver="batch_lm").local_ba_config(5).method == "batch_lm"
    assert GlobalBAConfig(solver="schur_lm").local_ba_config(5000).method == "schur_lm"


def test_both_solvers_reach_the_same_global_optimum():
    bmap, _, _ = perturbed_map()
    problem = global_ba_problem(bmap, BAWindowConfig())
    schur = run_global_ba(problem, GlobalBAConfig(solver="schur_lm"))
    gtsam = run_global_ba(problem, GlobalBAConfig(solver="batch_lm"))
    assert schur.stats["final_error"] == pytest.approx(gtsam.stats["final_error"], rel=1e-6)
    assert np.allclose(schur.T_world_cam, gtsam.T_world_cam, atol=1e-7)
    assert np.allclose(schur.p_world, gtsam.p_world, atol=1e-6)
    assert np.array_equal(schur.inlier_obs, gtsam.inlier_obs)
