"""Duplicate map point fusion with the neighbours (ORB-SLAM's ``SearchInNeighbors`` and ``Fuse``).

The new keyframe's points are projected into its first and second covisible neighbours, and
theirs into it. A projected point matches the keypoint with the closest descriptor inside a
square window (3 px x the predicted level's scale) whose level fits the prediction and whose
reprojection error passes the chi-square gate. If that keypoint has no point, it gets an
observation of the projected one; if it has another point, the two are merged, keeping the one
with more observations.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from zenslam.backend.map import BackendKeyframe, BackendMap, MapPoint, PointGeometry, frustum_projection

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class FusionConfig:
    """ORB-SLAM's neighbour fusion settings."""

    neighbours_stereo: int = 10  # first neighbours, stereo/RGB-D
    neighbours_mono: int = 20  # first neighbours, monocular
    second_neighbours: int = 5  # best covisible keyframes of each first neighbour added as targets
    search_radius_px: float = 3.0  # window half-size at level 0, x the predicted level's scale factor
    max_descriptor_distance: int = 50  # bits (ORB-SLAM TH_LOW)
    chi2_mono: float = 5.991  # reprojection gate, px^2 / level sigma^2
    chi2_stereo: float = 7.815  # same with the right-image u
    min_view_cos: float = 0.5  # viewing ray within 60 degrees of the point's mean viewing direction


def fusion_targets(bmap: BackendMap, kf_id: int, config: FusionConfig) -> list[int]:
    """The best covisible keyframes of ``kf_id`` and, after each, its own best ones (each once)."""
    mono = bmap.keyframe(kf_id).sensor == "mono"
    seen, targets = {kf_id}, []
    for first in bmap.covisibility.best_covisible(kf_id, config.neighbours_mono if mono else config.neighbours_stereo):
        if first in seen:
            continue
        seen.add(first)
        targets.append(first)
        for second in bmap.covisibility.best_covisible(first, config.second_neighbours):
            if second not in seen:
                seen.add(second)
                targets.append(second)
    return targets


def match_by_projection(kf: BackendKeyframe, points: list[MapPoint], config: FusionConfig) -> tuple[np.ndarray, np.ndarray]:
    """Best keypoint of ``kf`` for each projected point: (indices into ``points``, keypoint indices)."""
    descriptors = np.array([pt.descriptor for pt in points], dtype=np.uint8).reshape(-1, 32)
    return match_projected(kf, PointGeometry.of(points), descriptors, config)


def match_projected(
    kf: BackendKeyframe, geometry: PointGeometry, descriptors: np.ndarray, config: FusionConfig
) -> tuple[np.ndarray, np.ndarray]:
    """``match_by_projection`` of M points given as arrays (their descriptors (M, 32)): (point rows, keypoints)."""
    empty = np.zeros(0, dtype=np.int64)
    if len(descriptors) == 0 or kf.n_keypoints == 0:
        return empty, empty
    from zenslam.backend.fusion_search import best_in_windows
    from zenslam.compiled import kernel_array
    from zenslam.descriptor_words import words

    proj = frustum_projection(kf, geometry, config.min_view_cos)
    rows = np.flatnonzero(proj.visible)
    predicted = proj.level[rows]
    radius = config.search_radius_px * kf.scale_factors[predicted]
    order = kf.u_order()
    sorted_u = np.take(kf.keypoints_px[:, 0], order)
    u, v = np.take(proj.px[:, 0], rows), np.take(proj.px[:, 1], rows)
    lo = np.searchsorted(sorted_u, u - radius, side="right")  # keypoints with u strictly inside the window
    hi = np.searchsorted(sorted_u, u + radius, side="left")
    arrays = (
        rows, u, v, radius, predicted, np.take(proj.right_u, rows), lo, hi, order, kf.keypoints_px, kf.levels,
        kf.right_u, kf.level_sigma2,
    )  # fmt: skip
    best = best_in_windows(
        *(kernel_array(a, a.dtype) for a in arrays), float(config.chi2_mono), float(config.chi2_stereo),
        kernel_array(words(descriptors), np.uint64), kernel_array(words(kf.descriptors), np.uint64),
        int(config.max_descriptor_distance),
    )  # fmt: skip
    found = best >= 0
    return rows[found].astype(np.int64), best[found]


def fuse_into_keyframe(bmap: BackendMap, kf_id: int, point_ids: list[int], config: FusionConfig) -> int:
    """Project ``point_ids`` into ``kf_id`` and add observations or merge duplicates; returns matches applied."""
    ids = np.asarray([p for p in point_ids if p in bmap.points], dtype=np.int64)
    return _fuse_into(bmap, kf_id, ids, bmap.point_rows(ids), config)


def _observed_by(kf: BackendKeyframe, rows: np.ndarray, n_rows: int) -> np.ndarray:
    """(M,) bool: ``kf`` observes the point at store row ``rows[m]`` (of ``n_rows`` handed out): its
    associations' rows mirror the observations, marked on the store's rows (no sort)."""
    marked = np.zeros(n_rows + 1, dtype=bool)  # the last entry takes the -1 of keypoints without a point
    marked[kf.map_point_rows] = True
    return marked[rows]


def _fuse_into(bmap: BackendMap, kf_id: int, point_ids: np.ndarray, rows: np.ndarray, config: FusionConfig) -> int:
    """``fuse_into_keyframe`` of live points ``point_ids`` (M,) int64 at ``rows`` of the map's point store.

    The points' columns are read as the last refresh left them: nothing writes them before the next."""
    kf = bmap.keyframe(kf_id)
    live = bmap.points
    new = ~_observed_by(kf, rows, bmap.point_store.n_rows)
    candidates, rows = point_ids[new], rows[new]
    store = bmap.point_store
    matched, keypoints = match_projected(kf, PointGeometry.at(store, rows), np.take(store.descriptor, rows, axis=0), config)
    fused = 0
    for point_id, keypoint in zip(candidates[matched].tolist(), keypoints.tolist()):
        if point_id not in live or kf_id in live[point_id].observations:
            continue  # merged away, or moved into this keyframe by an earlier merge
        there = int(kf.map_point_ids[keypoint])
        if there < 0:
            bmap.add_observation(point_id, kf_id, keypoint)
        elif live[there].weighted_observations > live[point_id].weighted_observations:
            bmap.replace_point(point_id, there)
        else:
            bmap.replace_point(there, point_id)
        fused += 1
    return fused


def fuse_with_neighbours(bmap: BackendMap, kf_id: int, config: FusionConfig) -> int:
    """ORB-SLAM's ``SearchInNeighbors`` for keyframe ``kf_id``; returns matches applied both ways."""
    bmap.refresh_points()
    targets = fusion_targets(bmap, kf_id, config)
    fused = 0
    for target in targets:
        fused += _fuse_into(bmap, target, *bmap.keyframe_points(kf_id), config)
    if targets:
        ids, rows = (np.concatenate(parts) for parts in zip(*(bmap.keyframe_points(t) for t in targets)))
        _, first = np.unique(ids, return_index=True)
        first.sort()  # each point once, where it first appears
        fused += _fuse_into(bmap, kf_id, ids[first], rows[first], config)
    bmap.refresh_points()
    logger.debug("keyframe %d: %d fusion matches over %d target keyframes", kf_id, fused, len(targets))
    return fused
