"""New map points from the new keyframe's unmatched keypoints (ORB-SLAM's ``CreateNewMapPoints``).

For each of the keyframe's best covisible neighbours (with enough baseline), unmatched keypoints
of both are matched by descriptor under the epipolar constraint (``SearchForTriangulation``), then
triangulated linearly (SVD) or, when the rays are nearly parallel and a stereo depth is more
precise, back-projected from that depth (ORB-SLAM2's parallax rule). A point is kept when it is in
front of both cameras, reprojects within the chi-square gate in both and its distances to the two
cameras agree with the keypoints' pyramid levels.

As ORB-SLAM does, only keypoints under the same vocabulary node (of the feature vectors' level,
``PlaceRecognition.feature_nodes``) are compared; without a vocabulary every pair inside the
epipolar band is. The assignment is one-to-one, greedy by increasing descriptor distance (ties by
keypoint index). The nodes leave a small share of the pairs to test, which makes triangulation
cheaper than testing every pair in the band (benchmarks/local_mapping.md).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.descriptors import hamming_distance_rows
from zenslam.geometry import skew, transform_points

logger = logging.getLogger(__name__)

# The vocabulary node of each of a keyframe's features, from its id and (N, 32) descriptors:
# (N,) int64, -1 for a feature under none (``PlaceRecognition.feature_nodes``).
FeatureNodes = Callable[[int, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class TriangulationConfig:
    """ORB-SLAM2's new-point creation settings."""

    neighbours_stereo: int = 10  # best covisible keyframes searched, stereo/RGB-D
    neighbours_mono: int = 20  # best covisible keyframes searched, monocular
    max_descriptor_distance: int = 50  # bits (ORB-SLAM TH_LOW)
    match_ratio: float = 1.0  # best / second-best distance must be below this; 1.0 = off, as ORB-SLAM
    epipolar_chi2: float = 3.84  # squared px distance to the epipolar line / level sigma^2 (chi2 1 dof, 95%)
    epipole_min_distance_px: float = 10.0  # mono pairs: keypoints nearer the epipole than this x sqrt(scale) skipped
    min_baseline_depth_ratio: float = 0.01  # mono: baseline / neighbour's median scene depth below this -> skip it
    max_cos_parallax_mono: float = 0.9998  # without stereo, rays must diverge more (cos below this, about 1.1 deg)
    chi2_mono: float = 5.991  # reprojection gate, px^2 / level sigma^2 (chi2 2 dof, 95%)
    chi2_stereo: float = 7.815  # reprojection gate with the right-image u (chi2 3 dof, 95%)
    scale_consistency_factor: float = 1.5  # distance ratio vs octave ratio tolerance, x scale factor
    block_rows: int = 256  # keypoints of the new keyframe per block of the epipolar test (memory bound)


@dataclass(frozen=True)
class TriangulatedPoints:
    """Triangulation of matched keypoint pairs."""

    p_world: np.ndarray  # (M, 3) metres, world frame (undefined where not ok)
    ok: np.ndarray  # (M,) bool: passed parallax, depth, reprojection and scale checks


def fundamental_matrix(kf1: BackendKeyframe, kf2: BackendKeyframe) -> np.ndarray:
    """F12 (3, 3) with x1^T F12 x2 = 0 for pixels x1 in kf1 and x2 in kf2 of one world point."""
    T_1_2 = kf1.T_cam_world @ kf2.T_world_cam
    E = skew(T_1_2[:3, 3]) @ T_1_2[:3, :3]
    return kf1.K_inv.T @ E @ kf2.K_inv


def _epipolar_pairs(kf1, idx1, kf2, idx2, F12, config) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (into idx1, idx2) whose kf2 keypoint lies within the epipolar band."""
    x1h = np.column_stack([kf1.keypoints_px[idx1], np.ones(len(idx1))])
    lines = x1h @ F12  # (N1, 3): line a x + b y + c = 0 in kf2 per kf1 keypoint
    # Normalised lines give the signed distance in one product; float32 halves the memory
    # traffic, distances stay exact to ~1e-4 px at image scale.
    lines = (lines / np.maximum(np.hypot(lines[:, 0], lines[:, 1]), 1e-300)[:, None]).astype(np.float32)
    x2h = np.ascontiguousarray(np.column_stack([kf2.keypoints_px[idx2], np.ones(len(idx2))]).T, dtype=np.float32)
    gate = np.sqrt(config.epipolar_chi2 * kf2.level_sigma2[kf2.levels[idx2]]).astype(np.float32)  # (N2,) px
    rows, cols = [], []
    for start in range(0, len(idx1), config.block_rows):
        distance = np.abs(lines[start : start + config.block_rows] @ x2h)
        # flatnonzero + divmod: the same row-major pairs as nonzero, cheaper on a 2-D mask
        r, c = np.divmod(np.flatnonzero(distance < gate), len(idx2))
        rows.append(r + start)
        cols.append(c)
    return np.concatenate(rows), np.concatenate(cols)


def _node_runs(nodes1: np.ndarray, nodes2: np.ndarray, max_pairs: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The pairs of equal nodes (>= 0) as runs: row r of ``nodes1`` pairs with the rows
    ``order2[first[r]:first[r] + count[r]]`` of ``nodes2`` (ascending). None when there would be
    more than ``max_pairs`` pairs."""
    order2 = np.argsort(nodes2, kind="stable")
    sorted2 = nodes2[order2]
    first = np.searchsorted(sorted2, nodes1, "left")
    count = np.where(nodes1 >= 0, np.searchsorted(sorted2, nodes1, "right") - first, 0)
    if max_pairs is not None and int(count.sum()) > max_pairs:
        return None
    return order2, first, count


def _node_candidates(kf1, idx1, kf2, idx2, F12, config, runs, mono1, mono2):
    """``candidate_pairs`` among the pairs under one node (``runs``: ``_node_runs`` of the keypoints'
    nodes), one pair at a time (``epipolar_search``)."""
    from zenslam.backend.epipolar_search import node_pair_candidates
    from zenslam.compiled import kernel_array
    from zenslam.descriptor_words import words

    order2, first, count = runs
    lines = np.column_stack([kf1.keypoints_px[idx1], np.ones(len(idx1))]) @ F12  # (N1, 3): a x + b y + c = 0 in kf2
    epipole = _epipole(kf1, kf2)
    uv2 = kf2.keypoints_px[idx2]
    arrays = (
        lines, lines[:, 0] ** 2 + lines[:, 1] ** 2, first, count, order2, uv2,
        config.epipolar_chi2 * kf2.level_sigma2[kf2.levels[idx2]], idx1, words(kf1.descriptors), idx2,
        words(kf2.descriptors),
    )  # fmt: skip
    typed = [kernel_array(a, a.dtype) for a in arrays]
    flags = [kernel_array(a, np.bool_) for a in (mono1, mono2)]
    epipole_gate2 = _epipole_gate2(kf2, idx2, config) if epipole is not None else np.zeros(0)
    return node_pair_candidates(
        *typed, int(config.max_descriptor_distance), *flags, np.zeros(2) if epipole is None else epipole, epipole_gate2
    )


def candidate_pairs(
    kf1: BackendKeyframe,
    kf2: BackendKeyframe,
    idx1: np.ndarray,
    idx2: np.ndarray,
    F12: np.ndarray,
    config: TriangulationConfig,
    nodes: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keypoint pairs (i1 of kf1 among ``idx1``, i2 of kf2 among ``idx2``) in the epipolar band with
    descriptors close enough and, without stereo, not next to the epipole; and their distances, by
    i1's row in ``idx1`` then i2's in ``idx2``. With ``nodes`` (the vocabulary node of each keypoint
    of kf1 and of kf2), only pairs under the same node: few enough to test one by one, unless the
    vocabulary has few nodes at that level (more pairs than one block of the dense test), when the
    dense test is kept to the pairs under one node."""
    mono1, mono2 = kf1.right_u[idx1] < 0, kf2.right_u[idx2] < 0
    if nodes is not None:
        node1, node2 = nodes[0][idx1], nodes[1][idx2]
        runs = _node_runs(node1, node2, max_pairs=config.block_rows * len(idx2))
        if runs is not None:
            return _node_candidates(kf1, idx1, kf2, idx2, F12, config, runs, mono1, mono2)
    near_epipole = _near_epipole(kf1, kf2, idx2, config) if np.any(mono1) and np.any(mono2) else np.zeros(len(idx2), bool)
    r, c = _epipolar_pairs(kf1, idx1, kf2, idx2, F12, config)
    if nodes is not None:
        same = (node1[r] == node2[c]) & (node1[r] >= 0)
        r, c = r[same], c[same]
    i1, i2 = idx1[r], idx2[c]
    dist = hamming_distance_rows(kf1.descriptors, i1, kf2.descriptors, i2)
    keep = (dist <= config.max_descriptor_distance) & ~(mono1[r] & mono2[c] & near_epipole[c])
    return i1[keep], i2[keep], dist[keep]


def _epipole(kf1: BackendKeyframe, kf2: BackendKeyframe) -> np.ndarray | None:
    """(2,) pixels of kf1's centre in kf2's image, None when kf1 is not in front of kf2."""
    centre1_in_2 = transform_points(kf2.T_cam_world, kf1.centre_world[None])[0]
    if centre1_in_2[2] <= 1e-9:
        return None
    return (kf2.calibration.K @ (centre1_in_2 / centre1_in_2[2]))[:2]


def _epipole_gate2(kf2: BackendKeyframe, idx2: np.ndarray, config: TriangulationConfig) -> np.ndarray:
    """(N2,) squared pixels: how near the epipole kf2's keypoints ``idx2`` may not be, by their level."""
    return config.epipole_min_distance_px**2 * kf2.scale_factors[kf2.levels[idx2]]


def _near_epipole(kf1: BackendKeyframe, kf2: BackendKeyframe, idx2: np.ndarray, config: TriangulationConfig) -> np.ndarray:
    """(N2,) bool: kf2's keypoints ``idx2`` next to the epipole, where rays without stereo are nearly
    parallel and triangulate badly; none when kf1 is not in front."""
    epipole = _epipole(kf1, kf2)
    if epipole is None:
        return np.zeros(len(idx2), dtype=bool)
    d2 = np.sum((kf2.keypoints_px[idx2] - epipole) ** 2, axis=1)
    return d2 < _epipole_gate2(kf2, idx2, config)


def _one_to_one(i1: np.ndarray, i2: np.ndarray, dist: np.ndarray, config: TriangulationConfig) -> tuple[np.ndarray, np.ndarray]:
    """Greedy one-to-one assignment by increasing distance (ties by i1, then i2), sorted by i1; the
    ratio test first when enabled. Returns indices into the candidates."""
    at = np.arange(len(i1))
    if config.match_ratio < 1.0 and len(i1):
        at = _ratio_test(i1, i2, dist, config.match_ratio)
    order = at[np.lexsort((i2[at], i1[at], dist[at]))]
    used1, used2 = set(), set()
    chosen = []
    for k, a, b in zip(order.tolist(), i1[order].tolist(), i2[order].tolist()):
        if a in used1 or b in used2:
            continue
        used1.add(a)
        used2.add(b)
        chosen.append(k)
    chosen_arr = np.asarray(chosen, dtype=np.int64)
    return chosen_arr[np.argsort(i1[chosen_arr], kind="stable")]


def match_for_triangulation(
    kf1: BackendKeyframe, kf2: BackendKeyframe, F12: np.ndarray, config: TriangulationConfig
) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matches (keypoint indices idx1 in kf1, idx2 in kf2) between keypoints without a map point."""
    empty = np.zeros(0, dtype=np.int64)
    idx1 = np.flatnonzero(kf1.map_point_ids < 0)
    idx2 = np.flatnonzero(kf2.map_point_ids < 0)
    if len(idx1) == 0 or len(idx2) == 0:
        return empty, empty
    i1, i2, dist = candidate_pairs(kf1, kf2, idx1, idx2, F12, config)
    chosen = _one_to_one(i1, i2, dist, config)
    return i1[chosen], i2[chosen]


def _ratio_test(i1, i2, dist, ratio) -> np.ndarray:
    """Indices of the candidates of kf1 keypoints whose best distance beats ratio x the second best."""
    order = np.lexsort((i2, dist, i1))
    s1, sd = i1[order], dist[order]
    first = np.flatnonzero(np.r_[True, s1[1:] != s1[:-1]])
    counts = np.diff(np.r_[first, len(s1)])
    second = np.where(counts > 1, sd[np.minimum(first + 1, len(s1) - 1)], np.iinfo(np.int32).max)
    good = sd[first] < ratio * second
    return order[first[good]]


def _linear_triangulation(P1: np.ndarray, P2: np.ndarray, xn1: np.ndarray, xn2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """DLT from normalised coordinates (M, 2) and world -> camera 3x4 matrices (P2 may be one per
    pair, (M, 3, 4)); (points (M, 3), valid)."""
    P2 = np.broadcast_to(P2, (len(xn2), 3, 4))
    A = np.stack(
        [
            xn1[:, :1] * P1[2] - P1[0],
            xn1[:, 1:2] * P1[2] - P1[1],
            xn2[:, :1] * P2[:, 2] - P2[:, 0],
            xn2[:, 1:2] * P2[:, 2] - P2[:, 1],
        ],
        axis=1,
    )
    X = np.linalg.svd(A)[2][:, 3]
    w = X[:, 3]
    valid = np.abs(w) > 1e-12
    return X[:, :3] / np.where(valid, w, 1.0)[:, None], valid


def _normalised(kf: BackendKeyframe, idx: np.ndarray) -> np.ndarray:
    c = kf.calibration
    uv = kf.keypoints_px[idx]
    return np.column_stack([(uv[:, 0] - c.cx) / c.fx, (uv[:, 1] - c.cy) / c.fy])


def _stereo_parallax_cos(kf: BackendKeyframe, idx: np.ndarray, stereo: np.ndarray) -> np.ndarray:
    """cos of the angle the stereo baseline subtends at the keypoint's depth (2 where no stereo)."""
    baseline = kf.calibration.baseline_m or 0.0
    depth = np.where(stereo, kf.depth_m[idx], 1.0)
    return np.where(stereo, np.cos(2.0 * np.arctan2(baseline / 2.0, depth)), 2.0)


def triangulate_matches(
    kf1: BackendKeyframe, kf2: BackendKeyframe, idx1: np.ndarray, idx2: np.ndarray, config: TriangulationConfig
) -> TriangulatedPoints:
    """Triangulate matched keypoints (idx1 of kf1, idx2 of kf2) and apply ORB-SLAM2's checks."""
    return triangulate_pairs(kf1, [kf2], np.zeros(len(idx1), dtype=np.int64), idx1, idx2, config)


class _PerKeyframe:
    """Pairs grouped by their second keyframe: per-pair arrays filled one keyframe at a time, with
    the same array operations a single-keyframe call makes on its pairs."""

    def __init__(self, kf2s: list[BackendKeyframe], which: np.ndarray) -> None:
        self.kf2s = kf2s
        self.n = len(which)
        order = np.argsort(which, kind="stable")
        bounds = np.flatnonzero(np.diff(which[order])) + 1
        self.groups = [(kf2s[int(which[sel[0]])], sel) for sel in np.split(order, bounds)] if len(order) else []

    def fill(self, compute, shape: tuple[int, ...] = (), dtype=float, where: np.ndarray | None = None) -> np.ndarray:
        """(n, *shape) with ``compute(kf2, sel)`` at the pairs ``sel`` of each keyframe (only where ``where``)."""
        out = np.zeros((self.n, *shape), dtype=dtype)
        for kf2, sel in self.groups:
            if where is not None:
                sel = sel[where[sel]]
            if len(sel):
                out[sel] = compute(kf2, sel)
        return out


def triangulate_pairs(
    kf1: BackendKeyframe, kf2s: list[BackendKeyframe], which: np.ndarray, idx1: np.ndarray, idx2: np.ndarray,
    config: TriangulationConfig,
) -> TriangulatedPoints:
    """Triangulate keypoint pairs (idx1[m] of kf1, idx2[m] of ``kf2s[which[m]]``) and apply ORB-SLAM2's
    checks; each pair's result is the one ``triangulate_matches`` gives it."""
    per = _PerKeyframe(kf2s, np.asarray(which, dtype=np.int64))
    xn1 = _normalised(kf1, idx1)
    xn2 = per.fill(lambda kf2, sel: _normalised(kf2, idx2[sel]), (2,))
    ray1 = np.column_stack([xn1, np.ones(len(idx1))]) @ kf1.T_world_cam[:3, :3].T
    ray2 = per.fill(lambda kf2, sel: np.column_stack([xn2[sel], np.ones(len(sel))]) @ kf2.T_world_cam[:3, :3].T, (3,))
    cos_rays = np.einsum("ij,ij->i", ray1, ray2) / (np.linalg.norm(ray1, axis=1) * np.linalg.norm(ray2, axis=1))
    stereo1 = kf1.has_right[idx1] & (kf1.depth_m[idx1] > 0)
    stereo2 = per.fill(lambda kf2, sel: (kf2.right_u[idx2[sel]] >= 0) & (kf2.depth_m[idx2[sel]] > 0), dtype=bool)
    cos_s1 = np.where(stereo1, _stereo_parallax_cos(kf1, idx1, stereo1), cos_rays + 1.0)
    parallax2 = per.fill(lambda kf2, sel: _stereo_parallax_cos(kf2, idx2[sel], stereo2[sel]))
    cos_s2 = np.where(~stereo1 & stereo2, parallax2, cos_rays + 1.0)
    cos_stereo = np.minimum(cos_s1, cos_s2)
    linear = (cos_rays < cos_stereo) & (cos_rays > 0) & (stereo1 | stereo2 | (cos_rays < config.max_cos_parallax_mono))
    from1 = ~linear & stereo1 & (cos_s1 < cos_s2)
    from2 = ~linear & ~from1 & stereo2 & (cos_s2 < cos_s1)
    p_world = np.zeros((len(idx1), 3))
    ok = linear | from1 | from2
    if np.any(linear):
        P2 = per.fill(lambda kf2, sel: kf2.T_cam_world[:3], (3, 4), where=linear)[linear]
        X, valid = _linear_triangulation(kf1.T_cam_world[:3], P2, xn1[linear], xn2[linear])
        p_world[linear] = X
        ok[np.flatnonzero(linear)[~valid]] = False
    if np.any(from1):
        p_world[from1] = kf1.unproject(idx1[from1])
    if np.any(from2):
        p_world[from2] = per.fill(lambda kf2, sel: kf2.unproject(idx2[sel]), (3,), where=from2)[from2]
    reprojected2 = per.fill(lambda kf2, sel: _reprojection_ok(kf2, idx2[sel], p_world[sel], config), dtype=bool)
    ok &= _reprojection_ok(kf1, idx1, p_world, config) & reprojected2
    dist1 = np.linalg.norm(p_world - kf1.centre_world, axis=1)
    dist2 = np.linalg.norm(p_world - per.fill(lambda kf2, sel: kf2.centre_world, (3,)), axis=1)
    ratio_dist = dist2 / np.maximum(dist1, 1e-12)
    ratio_octave = kf1.scale_factors[kf1.levels[idx1]] / per.fill(lambda kf2, sel: kf2.scale_factors[kf2.levels[idx2[sel]]])
    factor = config.scale_consistency_factor * kf1.scale_factor
    ok &= (dist1 > 0) & (dist2 > 0) & (ratio_dist * factor >= ratio_octave) & (ratio_dist <= ratio_octave * factor)
    return TriangulatedPoints(p_world, ok)


def _reprojection_ok(kf: BackendKeyframe, idx: np.ndarray, p_world: np.ndarray, config: TriangulationConfig) -> np.ndarray:
    """In front of the camera and inside the chi-square gate (stereo keypoints include right u)."""
    px, right_u, z = kf.project(p_world)
    err2 = np.sum((px - kf.keypoints_px[idx]) ** 2, axis=1)
    stereo = kf.has_right[idx]
    err2_stereo = err2 + np.where(stereo, (np.nan_to_num(right_u) - kf.right_u[idx]) ** 2, 0.0)
    sigma2 = kf.level_sigma2[kf.levels[idx]]
    gate = np.where(stereo, err2_stereo <= config.chi2_stereo * sigma2, err2 <= config.chi2_mono * sigma2)
    return (z > 0) & gate


def scene_median_depth(bmap: BackendMap, kf: BackendKeyframe) -> float | None:
    """Median depth (metres) of the keyframe's map points in its camera, None without points."""
    ids = kf.map_point_ids[kf.map_point_ids >= 0]
    if len(ids) == 0:
        return None
    p_world = np.stack([bmap.points[int(p)].p_world for p in ids])
    return float(np.median(transform_points(kf.T_cam_world, p_world)[:, 2]))


def _neighbours(bmap: BackendMap, kf1: BackendKeyframe, config: TriangulationConfig) -> list[BackendKeyframe]:
    """The best covisible keyframes of ``kf1`` far enough from it to triangulate with (in order)."""
    mono = kf1.sensor == "mono"
    out = []
    for kf2_id in bmap.covisibility.best_covisible(kf1.id, config.neighbours_mono if mono else config.neighbours_stereo):
        kf2 = bmap.keyframe(kf2_id)
        baseline = float(np.linalg.norm(kf2.centre_world - kf1.centre_world))
        if not mono:
            if baseline < (kf2.calibration.baseline_m or 0.0):
                continue
        else:
            median = scene_median_depth(bmap, kf2)
            if median is None or median <= 0 or baseline / median < config.min_baseline_depth_ratio:
                continue
        out.append(kf2)
    return out


def create_new_points(bmap: BackendMap, kf_id: int, config: TriangulationConfig, feature_nodes: FeatureNodes | None = None) -> list[int]:
    """Triangulate new map points between ``kf_id`` and its best covisible keyframes; returns their ids.

    Each new point is observed by both keyframes; ids come from the map's backend id space. With
    ``feature_nodes``, keypoints are paired only under the same vocabulary node.
    Neighbours are served in order, each from the keypoints of ``kf_id`` still without a point. The
    candidate pairs of all of them are found and triangulated at once beforehand (a pair's result
    does not depend on the others), from the keypoints free at the start; each neighbour's
    assignment then skips those taken by the ones before it.
    """
    kf1 = bmap.keyframe(kf_id)
    neighbours = _neighbours(bmap, kf1, config)
    idx1 = np.flatnonzero(kf1.map_point_ids < 0)
    nodes1 = feature_nodes(kf1.id, kf1.descriptors) if feature_nodes is not None and neighbours else None
    parts = []
    for j, kf2 in enumerate(neighbours):
        idx2 = np.flatnonzero(kf2.map_point_ids < 0)
        if len(idx1) and len(idx2):
            nodes = None if nodes1 is None else (nodes1, feature_nodes(kf2.id, kf2.descriptors))
            i1, i2, dist = candidate_pairs(kf1, kf2, idx1, idx2, fundamental_matrix(kf1, kf2), config, nodes)
            parts.append((np.full(len(i1), j, dtype=np.int64), i1, i2, dist))
    if not parts:
        return []
    which, i1, i2, dist = (np.concatenate(a) for a in zip(*parts))
    result = triangulate_pairs(kf1, neighbours, which, i1, i2, config)
    created: list[int] = []
    taken = np.zeros(kf1.n_keypoints, dtype=bool)
    for j, kf2 in enumerate(neighbours):
        mine = np.flatnonzero((which == j) & ~taken[i1])
        matches = mine[_one_to_one(i1[mine], i2[mine], dist[mine], config)]
        good = matches[result.ok[matches]]
        created.extend(bmap.new_points_between(result.p_world[good], kf_id, i1[good], kf2.id, i2[good]))
        taken[i1[good]] = True
        logger.debug("keyframe %d x %d: %d matches, %d new points", kf_id, kf2.id, len(matches), len(good))
    return created
