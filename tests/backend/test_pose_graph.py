"""Essential-graph optimisation corrects a drifting loop, rejects a wrong one, fixes Sim(3) scale drift,
and moves map points with their reference keyframe."""

import numpy as np
import pytest

from zenslam.backend.essential_graph import EssentialEdge
from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.backend.pose_graph import (
    PoseGraphConfig,
    PoseGraphError,
    PoseGraphResult,
    correct_points_after_pose_graph,
    correction_and_path,
    optimize_essential_graph,
)
from zenslam.camera import PinholeCalibration
from zenslam.geometry import invert_T, make_T, so3_exp

N = 120  # keyframes 0.5 m apart: a 57.5 m lap, then keyframe N-1 revisits keyframe 4
REVISITED = 4


def circle(n=N, step_m=0.5):
    per_lap = n - (REVISITED + 1)
    radius = step_m * per_lap / (2 * np.pi)
    poses = []
    for i in range(n):
        a = 2 * np.pi * i / per_lap
        forward, down = np.array([-np.sin(a), np.cos(a), 0.0]), np.array([0.0, 0.0, -1.0])
        poses.append(make_T(np.column_stack([np.cross(down, forward), down, forward]), radius * np.array([np.cos(a), np.sin(a), 0])))
    return np.array(poses)


def drifting_loop(seed=0, yaw_bias=0.0005, scale_drift=0.0, loop=REVISITED):
    """Truth, the map's drifted poses and the loop correction of keyframe N-1 matched to ``loop``
    with the transform of the true revisit (``loop`` != REVISITED: an aliased, wrong place).
    ``scale_drift``: the map's units per metre shrink by this fraction per keyframe (monocular)."""
    rng = np.random.default_rng(seed)
    truth = circle()
    before = [truth[0]]
    for i in range(N - 1):
        z = invert_T(truth[i]) @ truth[i + 1] @ make_T(so3_exp(rng.normal(scale=3e-4, size=3) + [0, yaw_bias, 0]), rng.normal(scale=0.003, size=3))
        z[:3, 3] *= (1.0 - scale_drift) ** i
        before.append(before[-1] @ z)
    before = np.array(before)
    cur = N - 1
    S_loop_cur = invert_T(truth[REVISITED]) @ truth[cur]
    units = lambda k: (1.0 - scale_drift) ** max(k - 1, 0)  # noqa: E731  map units per metre near keyframe k
    S_loop_cur[:3, 3] *= units(loop)
    S_loop_cur[:3, :3] *= units(loop) / units(cur)
    S_world_cur = before[loop] @ S_loop_cur
    corrected = {k: S_world_cur @ invert_T(before[cur]) @ before[k] for k in range(cur - 3, cur + 1)}
    new_loop_edges = [(j, i) for i in corrected for j in range(loop - 2, loop + 3) if abs(i - (cur - loop) - j) <= 2]
    edges = [EssentialEdge(i - 1, i, "spanning_tree") for i in range(1, N)]
    edges += [EssentialEdge(i - d, i, "covisibility") for d in (2, 3) for i in range(d, N)]
    poses_before = {k: before[k] for k in range(N)}
    return truth, poses_before, corrected, sorted(edges), new_loop_edges, {loop}


def positions(poses):
    return np.array([poses[k][:3, 3] for k in range(N)])


def test_correct_loop_removes_the_drift():
    truth, before, corrected, edges, new_loop, fixed = drifting_loop()
    result = optimize_essential_graph(before, corrected, edges, new_loop, fixed, False, PoseGraphConfig())
    end_before = np.linalg.norm(before[N - 1][:3, 3] - truth[N - 1, :3, 3])
    end_after = np.linalg.norm(result.T_world_cam[N - 1][:3, 3] - truth[N - 1, :3, 3])
    assert end_before > 0.5  # the drift is real: 3 degrees of heading, over half a metre at the revisit
    assert end_after < end_before / 20
    mean_before = np.mean(np.linalg.norm(positions(before) - truth[:, :3, 3], axis=1))
    mean_after = np.mean(np.linalg.norm(positions(result.T_world_cam) - truth[:, :3, 3], axis=1))
    assert mean_after < mean_before / 3
    assert not result.stats["loop_rejected"] and min(result.loop_edge_weights.values()) > 0.5
    assert np.array_equal(result.T_world_cam[REVISITED], before[REVISITED])  # the loop keyframe is held
    assert all(s == 1.0 for s in result.scale.values())
    assert set(result.loop_edge_weights) == {(min(e), max(e)) for e in new_loop}


def test_wrong_loop_has_no_effect():
    truth, before, corrected, edges, new_loop, fixed = drifting_loop(loop=REVISITED + 40)  # 20 m along the lap
    result = optimize_essential_graph(before, corrected, edges, new_loop, fixed, False, PoseGraphConfig())
    assert result.stats["loop_rejected"]
    assert max(result.loop_edge_weights.values()) < 0.5
    assert np.abs(positions(result.T_world_cam) - positions(before)).max() < 1e-9
    # without robustness the same loop drags the map tens of metres
    plain = optimize_essential_graph(before, corrected, edges, new_loop, fixed, False, PoseGraphConfig(robust="none"))
    assert np.abs(positions(plain.T_world_cam) - positions(before)).max() > 5.0


def test_sim3_graph_corrects_scale_drift():
    truth, before, corrected, edges, new_loop, fixed = drifting_loop(scale_drift=0.002)
    assert np.linalg.det(corrected[N - 1][:3, :3]) ** (1 / 3) > 1.2  # the loop carries the scale ratio
    result = optimize_essential_graph(before, corrected, edges, new_loop, fixed, True, PoseGraphConfig())
    end_before = np.linalg.norm(before[N - 1][:3, 3] - truth[N - 1, :3, 3])
    end_after = np.linalg.norm(result.T_world_cam[N - 1][:3, 3] - truth[N - 1, :3, 3])
    assert end_before > 1.5 and end_after < end_before / 20
    # consecutive keyframes are 0.5 m apart again once each is scaled by its similarity
    centres = positions(result.T_world_cam)
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    assert np.abs(steps[-20:] - 0.5).max() < 0.05
    assert result.scale[N - 1] == pytest.approx(1.0 / 0.998 ** (N - 2), rel=0.05)
    # a rigid graph cannot take the scaled correction
    with pytest.raises(PoseGraphError, match="with_scale=True"):
        optimize_essential_graph(before, corrected, edges, new_loop, fixed, False, PoseGraphConfig())


def test_sim3_wrong_loop_has_no_effect():
    truth, before, corrected, edges, new_loop, fixed = drifting_loop(scale_drift=0.002, loop=N // 2)
    result = optimize_essential_graph(before, corrected, edges, new_loop, fixed, True, PoseGraphConfig())
    assert result.stats["loop_rejected"]
    assert np.abs(positions(result.T_world_cam) - positions(before)).max() < 1e-9
    assert all(s == pytest.approx(1.0) for s in result.scale.values())


def test_shared_covisibility_information_lets_a_dense_chain_take_a_true_loop():
    """Four covisibility edges per keyframe, all at the spanning tree's sigmas, make the chain too stiff
    for 0.6 m of true drift; sharing their information (sigmas x sqrt(4)) accepts and removes it,
    and still rejects a wrong loop 20 m along the lap."""
    truth, before, corrected, _, new_loop, fixed = drifting_loop()
    dense = [EssentialEdge(i - 1, i, "spanning_tree") for i in range(1, N)]
    dense += [EssentialEdge(i - d, i, "covisibility") for d in range(2, 6) for i in range(d, N)]
    full = optimize_essential_graph(before, corrected, sorted(dense), new_loop, fixed, False, PoseGraphConfig(covisibility_information="full"))
    assert full.stats["loop_rejected"]
    shared_config = PoseGraphConfig(covisibility_information="shared")
    shared = optimize_essential_graph(before, corrected, sorted(dense), new_loop, fixed, False, shared_config)
    assert not shared.stats["loop_rejected"]
    end_before = np.linalg.norm(before[N - 1][:3, 3] - truth[N - 1, :3, 3])
    assert end_before > 0.5 and np.linalg.norm(shared.T_world_cam[N - 1][:3, 3] - truth[N - 1, :3, 3]) < end_before / 20
    _, before, corrected, _, new_loop, fixed = drifting_loop(loop=REVISITED + 40)
    wrong = optimize_essential_graph(before, corrected, sorted(dense), new_loop, fixed, False, shared_config)
    assert wrong.stats["loop_rejected"]
    with pytest.raises(PoseGraphError, match="covisibility_information"):
        PoseGraphConfig(covisibility_information="half")


def test_monocular_graphs_share_covisibility_information_by_default():
    """A Sim(3) graph with four covisibility edges per keyframe and 0.2% scale drift per keyframe: the
    default (monocular "shared") takes the true loop, "full" rejects it; the stereo setting does not
    apply to Sim(3) graphs; a wrong loop is still rejected."""
    truth, before, corrected, _, new_loop, fixed = drifting_loop(scale_drift=0.002)
    dense = [EssentialEdge(i - 1, i, "spanning_tree") for i in range(1, N)]
    dense += [EssentialEdge(i - d, i, "covisibility") for d in range(2, 6) for i in range(d, N)]
    default = optimize_essential_graph(before, corrected, sorted(dense), new_loop, fixed, True, PoseGraphConfig())
    assert not default.stats["loop_rejected"]
    end_before = np.linalg.norm(before[N - 1][:3, 3] - truth[N - 1, :3, 3])
    assert end_before > 1.5 and np.linalg.norm(default.T_world_cam[N - 1][:3, 3] - truth[N - 1, :3, 3]) < end_before / 20
    stereo_shared_only = PoseGraphConfig(covisibility_information="shared", covisibility_information_monocular="full")
    full = optimize_essential_graph(before, corrected, sorted(dense), new_loop, fixed, True, stereo_shared_only)
    assert full.stats["loop_rejected"]
    _, before, corrected, _, new_loop, fixed = drifting_loop(scale_drift=0.002, loop=REVISITED + 40)
    wrong = optimize_essential_graph(before, corrected, sorted(dense), new_loop, fixed, True, PoseGraphConfig())
    assert wrong.stats["loop_rejected"]
    with pytest.raises(PoseGraphError, match="covisibility_information_monocular"):
        PoseGraphConfig(covisibility_information_monocular="half")


def test_correction_and_path_measure_the_move_against_the_keyframes_path():
    poses = {k: make_T(np.eye(3), [0.5 * k, 0.0, 0.0]) for k in range(10)}
    poses[12] = make_T(np.eye(3), [4.5, 1.0, 0.0])  # ids need not be consecutive: 10 and 11 were culled
    moved, path = correction_and_path(poses, 2, 12, make_T(np.eye(3), [4.5, 1.3, 0.4]))
    assert moved == pytest.approx(0.5)
    assert path == pytest.approx(7 * 0.5 + np.hypot(0.0, 1.0))  # keyframes 2..9, then 9 -> 12
    assert correction_and_path(poses, 12, 2, make_T(np.eye(3), [1.0, 0.0, 0.0]))[1] == pytest.approx(path)


def test_input_is_checked():
    truth, before, corrected, edges, new_loop, fixed = drifting_loop()
    with pytest.raises(PoseGraphError, match="fixed keyframes"):
        optimize_essential_graph(before, corrected, edges, new_loop, set(), False, PoseGraphConfig())
    with pytest.raises(PoseGraphError, match=r"keyframes \[500\]"):
        optimize_essential_graph(before, corrected, edges + [EssentialEdge(3, 500, "loop")], new_loop, fixed, False, PoseGraphConfig())
    bad = dict(before)
    bad[7] = np.diag([1.0, 2.0, 1.0, 1.0])
    with pytest.raises(PoseGraphError, match="not a similarity"):
        optimize_essential_graph(bad, corrected, edges, new_loop, fixed, False, PoseGraphConfig())


CAL = PinholeCalibration(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)


def small_map():
    """Keyframes 0, 1, 2 and points created by 0 and by 1 (point 5's creator, keyframe 2, no longer observes it)."""
    bmap = BackendMap()
    for k in range(3):
        n = 8
        bmap.add_keyframe(BackendKeyframe(
            id=k, stamp_ns=k, T_world_cam=make_T(np.eye(3), [k, 0.0, 0.0]), calibration=CAL, sensor="stereo",
            keypoints_px=np.zeros((n, 2)), levels=np.zeros(n, np.int64), angles_deg=np.zeros(n), right_u=np.full(n, -1.0),
            depth_m=np.full(n, -1.0), descriptors=np.zeros((n, 32), np.uint8), scale_factors=1.2 ** np.arange(8),
            map_point_ids=np.full(n, -1, np.int64),
        ))  # fmt: skip
    for pid, (creator, observers) in enumerate([(0, [0, 1]), (0, [0]), (1, [1, 2]), (1, [1]), (2, [2]), (2, [0, 1])]):
        bmap.add_point(pid, [pid, 1.0, 5.0], creator)
        for k in observers:
            bmap.add_observation(pid, k, pid)
    bmap.take_changes()
    return bmap


def test_points_move_with_their_reference_keyframe():
    bmap = small_map()
    before = {k: bmap.keyframes[k].T_world_cam.copy() for k in bmap.keyframes}
    after_T = {0: before[0], 1: make_T(so3_exp([0, 0.1, 0]), [1.5, 0.2, 0.0]), 2: make_T(so3_exp([0.05, 0, 0]), [2.0, -1.0, 0.5])}
    scale = {0: 1.0, 1: 1.0, 2: 2.0}
    result = PoseGraphResult(after_T, scale, before, {}, {})
    p_old = {pid: pt.p_world.copy() for pid, pt in bmap.points.items()}
    counts = correct_points_after_pose_graph(bmap, result)
    assert counts == {"keyframes": 3, "points": 6}
    reference = {0: 0, 1: 0, 2: 1, 3: 1, 4: 2, 5: 0}  # point 5: creator 2 does not observe it -> smallest observer
    for pid, ref in reference.items():
        S_after = result.S_world_cam(ref)
        p_cam = invert_T(before[ref]) @ np.append(p_old[pid], 1.0)
        assert np.allclose(bmap.points[pid].p_world, (S_after @ p_cam)[:3], atol=1e-12)
    # a point in front of its reference camera keeps its bearing there, scaled by the keyframe's scale
    p_cam_after = invert_T(bmap.keyframes[2].T_world_cam) @ np.append(bmap.points[4].p_world, 1.0)
    assert np.allclose(p_cam_after[:3], 2.0 * (invert_T(before[2]) @ np.append(p_old[4], 1.0))[:3])
    assert np.array_equal(bmap.keyframes[1].T_world_cam, after_T[1])
    changes = bmap.take_changes()
    assert changes.points == set(range(6)) and changes.keyframes == {0, 1, 2}
    assert bmap.check_consistency() == []


def test_points_of_keyframes_outside_the_result_stay():
    bmap = small_map()
    before = {k: bmap.keyframes[k].T_world_cam.copy() for k in bmap.keyframes}
    result = PoseGraphResult({0: make_T(np.eye(3), [0.0, 0.0, 1.0])}, {0: 1.0}, before, {}, {})
    correct_points_after_pose_graph(bmap, result)
    assert np.allclose(bmap.points[0].p_world, [0.0, 1.0, 6.0])  # reference keyframe 0 moved 1 m along z
    assert np.allclose(bmap.points[2].p_world, [2.0, 1.0, 5.0])  # reference keyframe 1 is not in the result
    assert np.array_equal(bmap.keyframes[1].T_world_cam, before[1])
