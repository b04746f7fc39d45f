"""Redundant keyframe culling (ORB-SLAM's ``LocalMapping::KeyFrameCulling``).

A keyframe covisible with the new one is redundant when more than 90% of its map points (for
stereo/RGB-D only its close points, depth below ``close_depth_baselines`` baselines) are seen by
at least three other keyframes at the same or a finer scale (keypoint level at most one above its
own). The first keyframe (the gauge) and keyframes holding a loop edge are never culled. Culling
removes the keyframe's observations, re-attaches its spanning-tree children and updates the
covisibility graph (``BackendMap.remove_keyframe``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from zenslam.backend.map import BackendKeyframe, BackendMap

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class KeyframeCullingConfig:
    """ORB-SLAM's redundancy test."""

    enabled: bool = True  # cull redundant keyframes at all
    redundant_fraction: float = 0.9  # culled when more than this fraction of its points is redundant
    min_other_observers: int = 3  # other keyframes that must see a point for it to be redundant
    level_margin: int = 1  # those keyframes' keypoint level may exceed this keyframe's by this much
    close_depth_baselines: float = 40.0  # stereo/RGB-D: only points closer than this x baseline count (ThDepth)


def is_redundant(bmap: BackendMap, kf_id: int, config: KeyframeCullingConfig) -> bool:
    """Whether keyframe ``kf_id`` is redundant under ORB-SLAM's rule."""
    return bool(redundant_keyframes(bmap, [kf_id], config)[0])


def _counted_keypoints(kf: BackendKeyframe, config: KeyframeCullingConfig) -> np.ndarray:
    """The keypoints of ``kf`` whose points the rule counts: all associated ones, for stereo/RGB-D
    only those with a depth below ``close_depth_baselines`` baselines."""
    keypoints = np.flatnonzero(kf.map_point_ids >= 0)
    if kf.sensor != "mono":
        th_depth = config.close_depth_baselines * (kf.calibration.baseline_m or 0.0)
        depth = kf.depth_m[keypoints]
        keypoints = keypoints[(depth >= 0) & (depth <= th_depth)]
    return keypoints


def redundant_keyframes(bmap: BackendMap, kf_ids: list[int], config: KeyframeCullingConfig) -> np.ndarray:
    """(K,) bool: ``is_redundant`` of each of ``kf_ids`` in the current map, all at once.

    A point's observers are the keyframes associating it, all among the keyframes sharing points
    with the one tested: their associations (store row, level) sorted by row give, for each
    counted keypoint, its point's other observers and their levels."""
    observer_ids = sorted(set(kf_ids).union(*(bmap.covisibility.weights(k) for k in kf_ids)))
    rows, owner, level = [], [], []
    for k in observer_ids:
        kf = bmap.keyframes[k]
        associated = np.flatnonzero(kf.map_point_rows >= 0)
        rows.append(kf.map_point_rows[associated])
        owner.append(np.full(len(associated), k, dtype=np.int64))
        level.append(kf.levels[associated])
    order = np.argsort(np.concatenate(rows), kind="stable")
    obs_row, obs_owner, obs_level = (np.concatenate(a)[order] for a in (rows, owner, level))
    tested = [_counted_keypoints(bmap.keyframes[k], config) for k in kf_ids]
    counts = np.array([len(t) for t in tested], dtype=np.int64)
    which = np.repeat(np.arange(len(kf_ids)), counts)  # (T,) the tested keyframe of each counted keypoint
    kp_row = np.concatenate([bmap.keyframes[k].map_point_rows[t] for k, t in zip(kf_ids, tested)] or [np.zeros(0, np.int64)])
    max_level = np.concatenate([bmap.keyframes[k].levels[t] for k, t in zip(kf_ids, tested)] or [np.zeros(0, np.int64)])
    max_level = max_level + config.level_margin
    start = np.searchsorted(obs_row, kp_row, "left")
    n = np.searchsorted(obs_row, kp_row, "right") - start
    entry = np.repeat(np.arange(len(kp_row)), n)
    at = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + np.repeat(start, n)
    tested_ids = np.asarray(kf_ids, dtype=np.int64)
    seen = (obs_owner[at] != tested_ids[which[entry]]) & (obs_level[at] <= max_level[entry])
    redundant_point = np.bincount(entry[seen], minlength=len(kp_row)) >= config.min_other_observers
    n_redundant = np.bincount(which[redundant_point], minlength=len(kf_ids))
    return n_redundant > config.redundant_fraction * counts


def cull_redundant_keyframes(bmap: BackendMap, current_id: int, config: KeyframeCullingConfig) -> tuple[list[int], list[int]]:
    """Remove the redundant keyframes among those connected to ``current_id`` (checked in connection
    order, each against the map left by the previous removals).

    Returns (culled keyframe ids, ids of points that lost an observation)."""
    if not config.enabled:
        return [], []
    culled: list[int] = []
    touched: list[int] = []
    candidates = [
        k for k in bmap.covisibility.connected(current_id)
        if k != bmap.first_keyframe_id and not bmap.essential_graph.has_loop_edge(k)
    ]  # fmt: skip
    while candidates:
        # All at once; a removal changes the others' verdicts, so those after it are tested again.
        redundant = redundant_keyframes(bmap, candidates, config)
        if not redundant.any():
            break
        first = int(np.argmax(redundant))
        touched.extend(bmap.remove_keyframe(candidates[first]))
        culled.append(candidates[first])
        candidates = candidates[first + 1 :]
    if culled:
        logger.debug("keyframe %d: culled redundant keyframes %s", current_id, culled)
    return culled, touched
