"""Essential-graph pose-graph optimisation after a loop closure (ORB-SLAM's OptimizeEssentialGraph).

Nodes are keyframes: ``gtsam.Pose3`` = T_world_cam for stereo/RGB-D maps, ``gtsam.Similarity3`` for
monocular ones, whose scale drifts and is corrected with the loop. Poses cross this module's
boundary as 4x4 similarities S_world_cam = [[s R, c], [0, 1]] (camera -> world, c the camera
centre, s = 1 for a rigid pose); gtsam's Similarity3 maps p -> s (R p + t), so it holds t = c / s.

Edges, as ORB-SLAM builds them: every spanning-tree edge, every covisibility pair sharing at least
the essential graph's weight, every loop edge closed earlier, each measured as the relative pose
of its ends *before* this correction (the map's poses: ORB-SLAM's NonCorrectedSim3 for the
corrected neighbourhood), plus the new loop edges between the corrected neighbourhood of the
current keyframe and the loop keyframe's neighbourhood, measured from their corrected poses.
Initial values are the corrected poses where given, the map's elsewhere; the loop keyframe is
held fixed (edges to a fixed keyframe become priors on the other end). Every edge has the same
diagonal noise (ORB-SLAM gives all edges identity information), or, where the graph's setting is
"shared" (by default monocular Sim(3) graphs), the covisibility edges' sigmas are scaled so that
together they weigh what the other edges weigh; loop edges -- new and old -- are the only ones that
may be wrong and the only ones made robust. The gtsam side lives in
``pose_graph_solver`` so that this module (point correction) loads without it; the configuration,
result and error both use are in ``pose_graph_types``.

Robustness against a wrong loop: a Cauchy kernel on the loop edges, Levenberg-Marquardt from the
corrected poses, and a rejection rule. A kernel alone cannot undo a wrong loop: the spanning tree
is a long chain, far more compliant than the cluster of new loop edges between two
neighbourhoods, so a least-squares start bends the chain to fit the loop almost exactly. From the
corrected start, LM keeps a loop the chain can absorb within its edges' noise (the loop edges stay
near zero residual, weight near 1) and drives the others out to the kernel's tail (weight near
0) -- but it leaves the graph wherever that took it, bent by the tail's pull, and in a Sim(3)
graph it can collapse the scale. So when every new loop edge ends with a weight below
``reject_below_weight`` the loop is rejected and the result is the poses before correction, which
are the optimum of the graph without it (every other edge was measured on them), reported in
``stats["loop_rejected"]``. GNC (gtsam.GncLMOptimizer, TLS, non-loop edges known inliers) under
the same rule sorts the same loops the same way on the benchmark's graphs, at several times the
time, and, without the rule, leaves a distorted graph where it rejects; it stays available as
``robust="gnc"``. What separates a wrong loop from drift is the
edge noise: a loop whose error the chain can absorb within a few sigma per edge is accepted,
right or wrong, so the sigmas are the drift a correct loop may show, and verification before
this step must stop wrong loops within that envelope. Figures: benchmarks/loop_geometry.md
(benchmarks/loop_geometry.py).
"""

from __future__ import annotations

import logging

import numpy as np

from zenslam.backend.essential_graph import EssentialEdge
from zenslam.backend.map import BackendMap
from zenslam.backend.pose_graph_types import PoseGraphConfig, PoseGraphError, PoseGraphResult, similarity_parts

logger = logging.getLogger(__name__)


def correction_and_path(
    poses: dict[int, np.ndarray], loop_kf: int, current_kf: int, S_current_corrected: np.ndarray
) -> tuple[float, float]:
    """How far a loop moves the current keyframe's camera centre, and the keyframes' path from the
    loop keyframe to it (the distances between consecutive keyframes by id, both ends included), in
    map units. ``poses``: camera -> world (rigid or similarities; the centre is the last column)."""
    lo, hi = sorted((int(loop_kf), int(current_kf)))
    ids = sorted(k for k in poses if lo <= k <= hi)
    centres = np.array([np.asarray(poses[k], dtype=float)[:3, 3] for k in ids]).reshape(-1, 3)
    path = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum())
    moved = np.asarray(S_current_corrected, dtype=float)[:3, 3] - np.asarray(poses[current_kf], dtype=float)[:3, 3]
    return float(np.linalg.norm(moved)), path


def optimize_essential_graph(
    poses_before: dict[int, np.ndarray],
    corrected: dict[int, np.ndarray],
    edges: list[EssentialEdge],
    new_loop_edges: list[tuple[int, int]],
    fixed: set[int],
    with_scale: bool,
    config: PoseGraphConfig,
) -> PoseGraphResult:
    """Optimise every keyframe of ``poses_before`` over the essential graph (see module docstring).

    ``poses_before``: every keyframe's pose before the correction (4x4, camera -> world; rigid, or
    similarities); ``corrected``: the corrected neighbourhood's poses (similarities when
    ``with_scale``); ``edges``: the essential graph's edges (an edge whose pair is also a new loop
    edge is replaced by it); ``new_loop_edges``: pairs measured from the corrected poses;
    ``fixed``: keyframes held where they start (at least one: the loop keyframe).
    """
    if not fixed or not set(fixed) <= set(poses_before):
        raise PoseGraphError(f"fixed keyframes {sorted(fixed)} must be non-empty and have poses; hold the loop keyframe")
    named = {k for e in edges for k in e[:2]} | {k for e in new_loop_edges for k in e} | set(corrected)
    unknown = sorted(named - set(poses_before))
    if unknown:
        raise PoseGraphError(f"keyframes {unknown[:10]} are in the pose graph's edges but have no pose before correction")
    from zenslam.backend.pose_graph_solver import solve  # gtsam: only where the optimisation runs

    return solve(poses_before, corrected, edges, new_loop_edges, set(fixed), with_scale, config)


def correct_points_after_pose_graph(
    bmap: BackendMap, result: PoseGraphResult, S_world_cam_before: dict[int, np.ndarray] | None = None
) -> dict[str, int]:
    """Write the optimised keyframe poses into ``bmap`` and move each point with its reference
    keyframe (``MapPoint.reference_keyframe_id``): p' = S_after S_before^-1 p.

    ``S_world_cam_before``: the poses the points agree with now (similarities); by default the
    optimisation's initial values, right when the corrected neighbourhood's points were moved with
    its corrected poses before the optimisation (ORB-SLAM's CorrectLoop). Keyframes missing from
    the result are left as they are, and so are their points. Returns counts of what moved.
    """
    before = result.S_world_cam_initial if S_world_cam_before is None else S_world_cam_before
    correction: dict[int, np.ndarray] = {}
    for k in bmap.keyframes:
        if k in result.T_world_cam and k in before:
            correction[k] = result.S_world_cam(k) @ _inverse_similarity(before[k])
    by_ref: dict[int, list[int]] = {}
    for point_id, point in bmap.points.items():
        ref = point.reference_keyframe_id
        if ref in correction:
            by_ref.setdefault(ref, []).append(point_id)
    moved = 0
    for ref in sorted(by_ref):
        ids = by_ref[ref]
        C = correction[ref]
        p = np.array([bmap.points[i].p_world for i in ids])
        bmap.set_point_positions(ids, p @ C[:3, :3].T + C[:3, 3])
        moved += len(ids)
    for k in sorted(correction):
        bmap.set_keyframe_pose(k, result.T_world_cam[k])
    return {"keyframes": len(correction), "points": moved}


def _inverse_similarity(S: np.ndarray) -> np.ndarray:
    """Inverse of [[s R, c], [0, 1]]: [[R^T / s, -R^T c / s], [0, 1]]."""
    R, c, s = similarity_parts(S)
    s = float(s)
    out = np.eye(4)
    out[:3, :3] = R.T / s
    out[:3, 3] = -R.T @ c / s
    return out
