"""Loop verification as ORB-SLAM2's ``LoopClosing::ComputeSim3``: is a consistent candidate really this place?

For each candidate in turn: matches between the current keyframe's and the candidate's map points
through the vocabulary's direct index (SearchByBoW); a RANSAC of the transform between the two
cameras from the matched points (rigid for stereo/RGB-D, with scale for monocular); more matches by
projecting each side's points through that transform (SearchBySim3); the transform refined on them
(OptimizeSim3). The first candidate keeping enough inliers gives the current keyframe's corrected
pose; the loop is accepted only if the points of the candidate's covisible neighbourhood, projected
with that pose, match enough of the current keyframe's keypoints (SearchByProjection).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.backend.point_fusion import FusionConfig, match_by_projection
from zenslam.backend.loop_closing_config import LoopVerificationConfig
from zenslam.backend.similarity import SimilarityMatches, find_similarity, optimize_similarity
from zenslam.geometry import transform_points
from zenslam.vocabulary import FeatureVector
from zenslam.vocabulary.bow_matching import search_by_bow

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class LoopMatch:
    """An accepted loop: the current keyframe, the candidate it closes on, and what was matched."""

    keyframe_id: int
    loop_keyframe_id: int
    T_cur_loop: np.ndarray  # (4, 4) rigid: with ``scale``, p_cur = scale R p_loop + t
    scale: float  # 1 for rigid (stereo/RGB-D) loops
    T_world_cur_corrected: np.ndarray  # (4, 4) the current keyframe's pose in the loop keyframe's map
    inliers: int  # matches kept by the transform's optimisation
    loop_point_ids: np.ndarray  # (M,) int64 points of the loop neighbourhood
    matched_keypoints: np.ndarray  # (K,) int64 keypoints of the current keyframe matched to a loop point
    matched_point_ids: np.ndarray  # (K,) int64 the loop points they matched


@dataclass(frozen=True)
class Rejection:
    """Why a consistent candidate was not accepted."""

    loop_keyframe_id: int
    reason: str
    # The verified match, when the candidate passed verification and was refused after it (by the
    # drift budget or the pose graph): what the loop asked for.
    match: LoopMatch | None = None


def verify_candidates(
    bmap: BackendMap,
    kf_id: int,
    candidates: list[int],
    feature_vectors: dict[int, FeatureVector],
    with_scale: bool,
    config: LoopVerificationConfig,
    seed: int,
) -> tuple[LoopMatch | None, list[Rejection]]:
    """The first of ``candidates`` (best first) that passes every check, and the rejections before it."""
    rejections: list[Rejection] = []
    current = bmap.keyframe(kf_id)
    for candidate_id in candidates:
        if candidate_id not in bmap.keyframes:
            continue
        match, reason = _verify_one(bmap, current, bmap.keyframe(candidate_id), feature_vectors, with_scale, config, seed)
        if match is not None:
            return match, rejections
        rejections.append(Rejection(candidate_id, reason))
        logger.debug("keyframe %d: loop candidate %d rejected: %s", kf_id, candidate_id, reason)
    return None, rejections


def _verify_one(
    bmap: BackendMap,
    current: BackendKeyframe,
    candidate: BackendKeyframe,
    feature_vectors: dict[int, FeatureVector],
    with_scale: bool,
    config: LoopVerificationConfig,
    seed: int,
) -> tuple[LoopMatch | None, str]:
    idx_cur, idx_cand = search_by_bow(
        feature_vectors[current.id], current.descriptors, current.angles_deg,
        feature_vectors[candidate.id], candidate.descriptors, candidate.angles_deg,
        usable_a=current.map_point_ids >= 0, usable_b=candidate.map_point_ids >= 0,
        ratio=config.bow_ratio,
    )
    if len(idx_cur) < config.min_bow_matches:
        return None, f"{len(idx_cur)} BoW matches < {config.min_bow_matches}"
    matches = _similarity_matches(bmap, current, candidate, idx_cur, idx_cand)
    estimate = find_similarity(matches, with_scale, config.ransac, np.random.default_rng(seed))
    if estimate is None:
        return None, f"no transform with {config.ransac.min_inliers} inliers among {len(idx_cur)} BoW matches"
    idx_cur, idx_cand = _search_by_transform(bmap, current, candidate, idx_cur, idx_cand, estimate.S_12, config)
    matches = _similarity_matches(bmap, current, candidate, idx_cur, idx_cand)
    refined = optimize_similarity(matches, estimate.T_12, estimate.scale, with_scale, config.optimization)
    inliers = 0 if refined is None else refined.n_inliers
    if refined is None or inliers < config.min_optimised_inliers:
        return None, f"{inliers} inliers after optimisation < {config.min_optimised_inliers}"
    T_world_cur = candidate.T_world_cam @ _inverse_similarity(refined.S_12)
    loop_points = _neighbourhood_points(bmap, candidate.id)
    keypoints, point_ids = _match_loop_points(bmap, current, T_world_cur, loop_points, config)
    if len(keypoints) < config.min_total_matches:
        return None, f"{len(keypoints)} loop points matched by projection < {config.min_total_matches}"
    return (
        LoopMatch(
            current.id, candidate.id, refined.T_12, refined.scale, T_world_cur, inliers, loop_points, keypoints, point_ids,
        ),
        "",
    )


def _inverse_similarity(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 similarity [sR t; 0 1] (a rigid transform when s = 1)."""
    sR, t = T[:3, :3], T[:3, 3]
    s2 = float(np.linalg.det(sR)) ** (2.0 / 3.0)
    inv = np.eye(4)
    inv[:3, :3] = sR.T / s2
    inv[:3, 3] = -inv[:3, :3] @ t
    return inv


def _similarity_matches(
    bmap: BackendMap, current: BackendKeyframe, candidate: BackendKeyframe, idx_cur: np.ndarray, idx_cand: np.ndarray
) -> SimilarityMatches:
    """Matched keypoints of the two keyframes with their points in each camera's frame."""
    p_world_1 = np.array([bmap.points[int(p)].p_world for p in current.map_point_ids[idx_cur]]).reshape(-1, 3)
    p_world_2 = np.array([bmap.points[int(p)].p_world for p in candidate.map_point_ids[idx_cand]]).reshape(-1, 3)
    return SimilarityMatches(
        p1_cam=transform_points(current.T_cam_world, p_world_1),
        p2_cam=transform_points(candidate.T_cam_world, p_world_2),
        px1=current.keypoints_px[idx_cur],
        px2=candidate.keypoints_px[idx_cand],
        sigma2_1=current.level_sigma2[current.levels[idx_cur]],
        sigma2_2=candidate.level_sigma2[candidate.levels[idx_cand]],
        calibration1=current.calibration,
        calibration2=candidate.calibration,
    )


def _search_by_transform(
    bmap: BackendMap,
    current: BackendKeyframe,
    candidate: BackendKeyframe,
    idx_cur: np.ndarray,
    idx_cand: np.ndarray,
    S_12: np.ndarray,
    config: LoopVerificationConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """SearchBySim3: the BoW matches plus those found by projecting each side's unmatched points into
    the other keyframe through ``S_12`` (4x4 similarity, candidate camera -> current camera); a pair
    is added only when found from both sides."""
    fusion = dataclasses.replace(FusionConfig(), search_radius_px=config.sim3_search_radius_px)
    matched_cur = set(idx_cur.tolist())
    matched_cand = set(idx_cand.tolist())
    cand_free = [k for k in np.flatnonzero(candidate.map_point_ids >= 0).tolist() if k not in matched_cand]
    cur_free = [k for k in np.flatnonzero(current.map_point_ids >= 0).tolist() if k not in matched_cur]
    # The current keyframe seen from where the transform puts it in the candidate's map, and back.
    cur_virtual = dataclasses.replace(current, T_world_cam=candidate.T_world_cam @ _inverse_similarity(S_12))
    cand_virtual = dataclasses.replace(candidate, T_world_cam=current.T_world_cam @ S_12)
    cand_points = [bmap.points[int(candidate.map_point_ids[k])] for k in cand_free]
    cur_points = [bmap.points[int(current.map_point_ids[k])] for k in cur_free]
    rows_12, kps_in_cur = match_by_projection(cur_virtual, cand_points, fusion)
    rows_21, kps_in_cand = match_by_projection(cand_virtual, cur_points, fusion)
    forward = {int(cand_free[r]): int(k) for r, k in zip(rows_12.tolist(), kps_in_cur.tolist())}
    backward = {int(cur_free[r]): int(k) for r, k in zip(rows_21.tolist(), kps_in_cand.tolist())}
    extra = sorted((k_cur, k_cand) for k_cand, k_cur in forward.items() if backward.get(k_cur) == k_cand)
    if not extra:
        return idx_cur, idx_cand
    add_cur, add_cand = (np.array(a, dtype=np.int64) for a in zip(*extra))
    return np.concatenate([idx_cur, add_cur]), np.concatenate([idx_cand, add_cand])


def _neighbourhood_points(bmap: BackendMap, kf_id: int) -> np.ndarray:
    """Points of ``kf_id`` and its covisible keyframes (ORB-SLAM's loop map points), ids ascending."""
    kfs = [kf_id] + bmap.covisibility.connected(kf_id)
    return np.unique(np.concatenate([bmap.keyframe_point_ids(k) for k in kfs])).astype(np.int64)


def _match_loop_points(
    bmap: BackendMap,
    current: BackendKeyframe,
    T_world_cur: np.ndarray,
    loop_points: np.ndarray,
    config: LoopVerificationConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints of ``current`` matched to loop points projected with the corrected pose, one point
    per keypoint (the lowest id when several chose it): (keypoints, point ids)."""
    fusion = dataclasses.replace(FusionConfig(), search_radius_px=config.projection_radius_px)
    virtual = dataclasses.replace(current, T_world_cam=T_world_cur)
    points = [bmap.points[int(p)] for p in loop_points.tolist()]
    rows, keypoints = match_by_projection(virtual, points, fusion)
    order = np.lexsort((rows, keypoints))
    rows, keypoints = rows[order], keypoints[order]
    first = np.r_[True, keypoints[1:] != keypoints[:-1]] if len(keypoints) else np.zeros(0, dtype=bool)
    return keypoints[first], loop_points[rows[first]]
