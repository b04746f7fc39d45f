"""Global bundle adjustment: every keyframe and map point of the map, after a loop closure.

ORB-SLAM runs it in a thread of its own after the essential-graph correction, while local mapping
keeps inserting keyframes, and applies the result when it ends. Here that is three steps:

1. ``global_ba_problem(bmap, window)`` on the map's owner: a ``BAProblem`` over every keyframe
   (the first one fixed: the gauge) and every observed point, built from copies of the map's
   arrays, with local BA's observation model (``BAWindowConfig``). Nothing in it refers to the map.
2. ``run_global_ba(problem, config)`` anywhere: a local BA solver (a Huber pass, outliers
   dropped, a plain pass) with the global schedule: local BA's own (``schur_lm``) for maps whose
   reduced camera system is small enough to solve densely, gtsam's sparse elimination above. It
   touches no shared state, and problem and result pickle, so it can run in another process. gtsam
   holds the GIL for the whole of an optimisation, so a Python thread running it stalls every
   other Python thread of the process until it returns: run it in a separate process to keep local
   mapping going (a worker thread only makes sense where nothing else needs the interpreter meanwhile).
3. ``apply_global_ba(bmap, problem, result)`` on the owner, when the owner decides: optimised poses
   and points written; keyframes inserted since the problem was built are corrected through the
   spanning tree (a child takes its parent's correction, root first, as ORB-SLAM), and points not
   optimised (new since, or left without an inlier observation) move with their reference
   keyframe's correction. Observations the optimiser classed as outliers are left in the map:
   the map may have changed meanwhile, and local mapping's BA and culling judge them again.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import deque
from dataclasses import dataclass
from typing import Literal

import numpy as np

from zenslam.backend.ba_problem import BAProblem, BAResult, LocalBAConfig
from zenslam.backend.local_mapping import BAWindowConfig, ba_problem, bundle_adjuster
from zenslam.backend.map import BackendMap
from zenslam.geometry import invert_T

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class GlobalBAConfig:
    """Schedule of global BA (ORB-SLAM: 10 iterations after a loop, no robust kernel)."""

    enabled: bool = True  # a global BA after each closed loop
    robust_iterations: int = 5  # first pass, Huber kernel on every observation (count; 0 = none)
    iterations: int = 10  # second pass, outliers of the first dropped, no kernel (count)
    # Elimination ordering (see LocalBAConfig.ordering): landmarks first leaves the keyframes' reduced
    # system, whose fill follows the covisibility graph.
    ordering: Literal["landmarks_first", "colamd", "metis"] = "landmarks_first"
    # A pass stops early when the error drops by less than this fraction in one iteration.
    relative_error_tolerance: float = 1e-4
    # The solver. schur_lm is local BA's: the points eliminated in compiled loops, then the reduced
    # camera system solved densely; it holds (6 x keyframes)^2 numbers and its solve grows with the
    # cube of the keyframes. batch_lm is gtsam's sparse elimination, whose cost follows the
    # covisibility graph instead. auto: schur_lm up to dense_max_keyframes keyframes, batch_lm above
    # (benchmarks/loop_closing.md measures both).
    solver: Literal["auto", "schur_lm", "batch_lm"] = "auto"
    dense_max_keyframes: int = 300

    def method(self, n_keyframes: int) -> Literal["schur_lm", "batch_lm"]:
        """The solver for a map of ``n_keyframes`` keyframes."""
        if self.solver != "auto":
            return self.solver
        return "schur_lm" if n_keyframes <= self.dense_max_keyframes else "batch_lm"

    def local_ba_config(self, n_keyframes: int = 0) -> LocalBAConfig:
        """The solver settings for a map of ``n_keyframes`` keyframes: local BA's thresholds with this schedule."""
        return dataclasses.replace(
            LocalBAConfig(),
            method=self.method(n_keyframes),
            robust_iterations=self.robust_iterations,
            refine_iterations=self.iterations,
            two_passes=True,
            ordering=self.ordering,
            relative_error_tolerance=self.relative_error_tolerance,
        )


@dataclass(frozen=True)
class GlobalBAProblem:
    """The problem and, per observation, the ids it stands for (so results can be matched to the map later)."""

    problem: BAProblem
    obs_point_ids: np.ndarray  # (O,) int64
    obs_keyframe_ids: np.ndarray  # (O,) int64


def global_ba_problem(bmap: BackendMap, window: BAWindowConfig) -> GlobalBAProblem | None:
    """Every keyframe of ``bmap`` (the first one fixed) and every point it observes, as copies; None
    when the map holds fewer than two keyframes or no observed point. Call where the map is owned."""
    kf_ids = list(bmap.keyframes)
    point_ids = sorted(p for p, pt in bmap.points.items() if pt.observations)
    if len(kf_ids) < 2 or not point_ids:
        return None
    first = bmap.first_keyframe_id
    is_fixed = np.array([k == first for k in kf_ids], dtype=bool)
    problem, obs_point_ids, obs_kf_ids = ba_problem(bmap, kf_ids, point_ids, is_fixed, bmap.keyframes[first].calibration, window)
    return GlobalBAProblem(problem, obs_point_ids, obs_kf_ids)


def run_global_ba(problem: GlobalBAProblem, config: GlobalBAConfig) -> BAResult:
    """Optimise the problem (no access to any map; safe in another thread or process)."""
    n_keyframes = len(problem.problem.keyframe_ids)
    result = bundle_adjuster(config.local_ba_config(n_keyframes)).optimize(problem.problem)
    logger.info(
        "global BA (%s): %d keyframes, %d points, %d iterations, %.0f ms", config.method(n_keyframes),
        n_keyframes, len(problem.problem.point_ids), result.stats["iterations"], result.stats["time_ms"],
    )  # fmt: skip
    return result


def apply_global_ba(bmap: BackendMap, problem: GlobalBAProblem, result: BAResult) -> dict[str, int]:
    """Write the result into ``bmap`` (see the module docstring); returns counts of what moved."""
    p = problem.problem
    new_pose = {int(k): result.T_world_cam[row] for row, k in enumerate(p.keyframe_ids.tolist()) if k in bmap.keyframes}
    optimised_kfs = len(new_pose)
    for kf_id in _tree_order(bmap):  # parents before children
        parent = bmap.spanning_tree.parent(kf_id)
        if kf_id not in new_pose and parent in new_pose:
            parent_now = bmap.keyframes[parent].T_world_cam
            new_pose[kf_id] = new_pose[parent] @ invert_T(parent_now) @ bmap.keyframes[kf_id].T_world_cam
    correction = {k: T @ invert_T(bmap.keyframes[k].T_world_cam) for k, T in new_pose.items()}

    removed = set(np.asarray(result.removed_point_ids).tolist())
    optimised_rows = [row for row, pid in enumerate(p.point_ids.tolist()) if pid in bmap.points and pid not in removed]
    optimised = {int(p.point_ids[row]) for row in optimised_rows}
    bmap.set_point_positions([int(p.point_ids[row]) for row in optimised_rows], result.p_world[optimised_rows])
    by_ref: dict[int, list[int]] = {}
    for point_id, point in bmap.points.items():
        ref = point.reference_keyframe_id
        if point_id not in optimised and ref in correction:
            by_ref.setdefault(ref, []).append(point_id)
    moved = 0
    for ref in sorted(by_ref):
        ids, C = by_ref[ref], correction[ref]
        bmap.set_point_positions(ids, np.array([bmap.points[i].p_world for i in ids]) @ C[:3, :3].T + C[:3, 3])
        moved += len(ids)
    for kf_id in sorted(new_pose):
        bmap.set_keyframe_pose(kf_id, new_pose[kf_id])
    counts = {
        "keyframes_optimised": optimised_kfs,
        "keyframes_propagated": len(new_pose) - optimised_kfs,
        "points_optimised": len(optimised_rows),
        "points_propagated": moved,
    }
    logger.debug("global BA applied: %s", counts)
    return counts


def _tree_order(bmap: BackendMap) -> list[int]:
    """Keyframes in breadth-first order of the spanning tree from its root (children by id)."""
    root = bmap.first_keyframe_id
    if root is None:
        return []
    order, queue = [], deque([root])
    while queue:
        kf_id = queue.popleft()
        order.append(kf_id)
        queue.extend(bmap.spanning_tree.children(kf_id))
    return order
