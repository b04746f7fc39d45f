"""The ``loops`` section of metrics.json: how far off the estimate is where the path comes back to its start.

Revisit frames come from the ground truth alone. Over the poses matched between estimate and ground
truth (in stamp order), with p_i the ground-truth camera centre of matched pose i and
``extent = max_i |p_i - p_0|``: the path has gone away once some |p_i - p_0| >= ``far_fraction``
* extent; after that, the first stretch of consecutive poses within ``radius_m`` of p_0 is a
return, and its pose closest to p_0 is the revisit. Then the path must go away again before the next
revisit (one per lap). A path whose far point is not beyond ``radius_m`` never goes away, so it has
no revisit.

The revisit error compares relative poses, so no alignment enters it: with G_i the ground truth and
E_i the estimate (T_world_cam), the error of revisit k is E = (G_0^-1 G_k)^-1 (E_0^-1 E_k), reported
as the length of its translation (metres) and the angle of its rotation (degrees). It is computed on
the evaluation's aligned estimate, whose relative poses equal the raw estimate's under SE(3) (or no)
alignment and carry the alignment's scale under Sim(3) (monocular).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.geometry import invert_T, so3_log
from zenslam.service.evaluation.metrics import Evaluation

DEFAULT_REVISIT_RADIUS_M = 1.0  # metres: how close to the start a return must come
DEFAULT_FAR_FRACTION = 0.5  # fraction of the path's extent from its start that counts as gone away


@dataclass(frozen=True)
class Revisit:
    """One return of the path to its start and the estimate's error there."""

    index: int  # matched-pose index of the revisit (0 is the start)
    stamp_ns: int
    distance_m: float  # ground-truth distance of the revisit's camera from the start's, metres
    translation_error_m: float  # length of the relative pose error's translation, metres
    rotation_error_deg: float  # angle of the relative pose error's rotation, degrees


def revisit_indices(
    p_world: np.ndarray, radius_m: float = DEFAULT_REVISIT_RADIUS_M, far_fraction: float = DEFAULT_FAR_FRACTION
) -> list[int]:
    """Indices of the revisits of a path of camera centres ``p_world`` (N, 3), metres (see the module doc)."""
    p_world = np.asarray(p_world, dtype=float)
    if len(p_world) < 2:
        return []
    distance = np.linalg.norm(p_world - p_world[0], axis=1)
    far_m = far_fraction * float(distance.max())
    if far_m <= radius_m:
        return []
    revisits: list[int] = []
    i = 0
    while True:
        away = np.flatnonzero(distance[i:] >= far_m)
        if len(away) == 0:
            return revisits
        start = i + int(away[0])
        back = np.flatnonzero(distance[start:] <= radius_m)
        if len(back) == 0:
            return revisits
        first = start + int(back[0])
        beyond = np.flatnonzero(distance[first:] > radius_m)
        end = first + int(beyond[0]) if len(beyond) else len(distance)
        revisits.append(first + int(np.argmin(distance[first:end])))
        i = end


def relative_pose_error(T_gt: np.ndarray, T_est: np.ndarray, i: int, k: int) -> tuple[float, float]:
    """(translation metres, rotation degrees) of (G_i^-1 G_k)^-1 (E_i^-1 E_k) for poses (N, 4, 4) T_world_cam."""
    rel_gt = invert_T(T_gt[i]) @ T_gt[k]
    rel_est = invert_T(T_est[i]) @ T_est[k]
    error = invert_T(rel_gt) @ rel_est
    return float(np.linalg.norm(error[:3, 3])), float(np.degrees(np.linalg.norm(so3_log(error[:3, :3]))))


def revisits(
    evaluation: Evaluation, radius_m: float = DEFAULT_REVISIT_RADIUS_M, far_fraction: float = DEFAULT_FAR_FRACTION
) -> list[Revisit]:
    """The revisits of an evaluation's matched poses and the estimate's relative pose error at each."""
    T_gt, T_est = evaluation.T_world_cam_gt, evaluation.T_world_cam_est_aligned
    stamps_ns = evaluation.stamps_ns
    out = []
    for k in revisit_indices(T_gt[:, :3, 3], radius_m, far_fraction):
        trans_m, rot_deg = relative_pose_error(T_gt, T_est, 0, k)
        distance_m = float(np.linalg.norm(T_gt[k, :3, 3] - T_gt[0, :3, 3]))
        out.append(Revisit(k, int(stamps_ns[k]), distance_m, trans_m, rot_deg))
    return out


def loops_section(tracked: Evaluation | None, final: Evaluation | None = None) -> dict[str, object]:
    """The ``loops`` section of metrics.json.

    ``revisit_error_m`` (metres) and ``revisit_rotation_error_deg`` are the first revisit's errors
    of ``final`` (the trajectory with mapping's and loop closing's later corrections) or, without it,
    of ``tracked``; ``revisit_error_tracked_m`` is the first revisit's error of the poses as tracked;
    ``revisits`` lists every revisit (one per lap) of the same trajectory as ``revisit_error_m``.
    Errors are null when there is no ground truth or the path never returns to its start.
    """
    chosen = final if final is not None else tracked
    found = revisits(chosen) if chosen is not None else []
    tracked_found = revisits(tracked) if tracked is not None else []
    first = found[0] if found else None
    return {
        "revisit_error_m": first.translation_error_m if first else None,
        "revisit_rotation_error_deg": first.rotation_error_deg if first else None,
        "revisit_stamp_ns": first.stamp_ns if first else None,
        "revisit_error_tracked_m": tracked_found[0].translation_error_m if tracked_found else None,
        "revisits": [
            {
                "stamp_ns": r.stamp_ns,
                "distance_m": r.distance_m,
                "error_m": r.translation_error_m,
                "rotation_error_deg": r.rotation_error_deg,
            }
            for r in found
        ],
    }
