"""The loop counts of metrics.json's ``loops`` section: candidates verified, accepted, rejected, judged by ground truth.

An accepted loop says where the current keyframe is relative to the loop keyframe
(``T_cur_loop``). With ground truth at both keyframes' stamps, the loop is a false accept when
that relative pose is off the truth's by more than ``max_translation_m`` or ``max_rotation_deg``.
A loop refused after verification (drift budget, pose graph) carries the transform it asked for:
its error against the truth says whether the refusal kept a wrong loop out or a true one.
A monocular map has a scale of its own: its translations are taken to metres with the scale of the
run's Sim(3) alignment to the ground truth (metres per map unit).
"""

from __future__ import annotations

import numpy as np

from zenslam.geometry import invert_T, so3_log
from zenslam.schemas import codec
from zenslam.trajectory import Trajectory

MAX_TRANSLATION_M = 0.3  # metres: an accepted loop whose relative pose is off by more is false
MAX_ROTATION_DEG = 5.0  # degrees: same for the rotation
MAX_STAMP_DIFF_NS = 20_000_000  # nanoseconds: ground truth this close to a keyframe's stamp is its pose


def _pose_at(ground_truth: Trajectory, stamp_ns: int) -> np.ndarray | None:
    """The ground-truth pose nearest ``stamp_ns`` within MAX_STAMP_DIFF_NS, or None."""
    stamps = np.asarray(ground_truth.stamps_ns, dtype=np.int64)
    if len(stamps) == 0:
        return None
    i = int(np.clip(np.searchsorted(stamps, stamp_ns), 1, len(stamps) - 1)) if len(stamps) > 1 else 0
    best = min((j for j in (i - 1, i) if 0 <= j < len(stamps)), key=lambda j: abs(int(stamps[j]) - stamp_ns))
    return np.asarray(ground_truth.T_world_cam[best]) if abs(int(stamps[best]) - stamp_ns) <= MAX_STAMP_DIFF_NS else None


def loop_error(loop: codec.LoopMessage, ground_truth: Trajectory, metres_per_unit: float = 1.0) -> tuple[float, float] | None:
    """(translation m, rotation deg) between a verified loop's ``T_cur_loop`` (its translation times
    ``metres_per_unit``) and the truth's, or None without ground truth at both stamps."""
    T_world_cur = _pose_at(ground_truth, loop.stamp_ns)
    T_world_loop = _pose_at(ground_truth, loop.loop_stamp_ns)
    if T_world_cur is None or T_world_loop is None:
        return None
    T_true = invert_T(T_world_cur) @ T_world_loop
    T_cur_loop = np.array(loop.T_cur_loop, dtype=float)
    T_cur_loop[:3, 3] *= metres_per_unit
    T_error = invert_T(T_true) @ T_cur_loop
    return float(np.linalg.norm(T_error[:3, 3])), float(np.degrees(np.linalg.norm(so3_log(T_error[:3, :3]))))


def acceptance_counts(
    loops: list[codec.LoopMessage], ground_truth: Trajectory | None, metres_per_unit: float = 1.0
) -> dict[str, object]:
    """Counts of verified candidates, accepted and rejected loops, and those rejected after
    verification (``refused``); with ground truth, the accepted loops that are false
    (``false_accepted``), each accepted loop's error and each refused loop's (``metres_per_unit``:
    the map's scale, 1 for stereo/RGB-D)."""
    accepted = [loop for loop in loops if loop.accepted]
    refused = [loop for loop in loops if not loop.accepted and loop.inliers > 0]
    section: dict[str, object] = {
        "candidates": len(loops),
        "accepted": len(accepted),
        "rejected": len(loops) - len(accepted),
        "refused": len(refused),
    }
    if ground_truth is None:
        return section
    judged = [(loop, loop_error(loop, ground_truth, metres_per_unit)) for loop in accepted]
    judged_accepted = [(loop, e) for loop, e in judged if e is not None]
    section["false_accepted"] = sum(1 for _, (t, r) in judged_accepted if t > MAX_TRANSLATION_M or r > MAX_ROTATION_DEG)
    section["accepted_without_ground_truth"] = len(judged) - len(judged_accepted)
    section["accepted_loops"] = [_judged(loop, e) for loop, e in judged_accepted]
    judged_refused = [(loop, loop_error(loop, ground_truth, metres_per_unit)) for loop in refused]
    section["refused_loops"] = [_judged(loop, e) | {"reason": loop.reason} for loop, e in judged_refused if e is not None]
    return section


def _judged(loop: codec.LoopMessage, error: tuple[float, float]) -> dict[str, object]:
    t, r = error
    return {"keyframe_id": int(loop.keyframe_id), "loop_keyframe_id": int(loop.loop_keyframe_id),
            "inliers": int(loop.inliers), "error_m": round(t, 4), "error_deg": round(r, 3)}  # fmt: skip
