"""Relocalisation: a lost frame's pose against candidate keyframes of the map (ORB-SLAM2's ``Relocalization``).

For each candidate keyframe, best first: the frame's keypoints are matched to the keyframe's
keypoints that observe a map point through the vocabulary's direct index (``search_by_bow``);
with at least ``min_bow_matches`` matches, a pose is sought by EPnP RANSAC on those 3D-2D matches,
then optimised (the tracker's pose optimisation, outliers dropped). When fewer than
``min_inliers`` remain, the keyframe's other points are projected with that pose and matched in
a coarse window, the pose optimised again, and, when it is close (more than
``narrow_min_inliers``), once more in a narrow window. The first candidate that reaches
``min_inliers`` inliers is the answer.

The candidates and their points come from the backend's reply (``RelocalisationCandidates``), so
the frame can be placed anywhere in the map, whether or not the frontend's cache holds that part.
Plain numpy/OpenCV: no bus, no tracker state.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from zenslam.errors import ConfigError
from zenslam.frontend.feature_matcher import rotation_consistent, search_by_projection
from zenslam.frontend.frame import Frame, frame_position_sigma, optimize_frame_pose
from zenslam.frontend.frustum import project_in_frustum
from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.orb_extractor import Features
from zenslam.frontend.pnp_ransac import PnpRansacConfig, pnp_ransac
from zenslam.pose_optimizer import PoseOptimizerConfig
from zenslam.schemas.relocalisation import MapKeyframe, MapPoints, RelocalisationCandidates
from zenslam.vocabulary.bow_matching import search_by_bow

logger = logging.getLogger(__name__)


class BowTransform(Protocol):
    """What relocalisation needs of a vocabulary (``zenslam.vocabulary.Vocabulary``)."""

    def transform(self, descriptors: np.ndarray) -> tuple[Any, Any]: ...


@dataclass(frozen=True)
class RelocalisationConfig:
    """When and how a lost frame is relocalised (ORB-SLAM2's thresholds unless noted)."""

    enabled: bool = True  # relocalise a lost frame against the backend's map (needs the backend)
    max_candidates: int = 5  # candidate keyframes asked of the backend and tried, best first (count)
    max_neighbours: int = 10  # covisible neighbours sent with each candidate (ORB-SLAM's local window: 10)
    min_bow_matches: int = 15  # bag-of-words matches needed to try a candidate
    bow_max_distance: int = 50  # Hamming bits (ORB-SLAM's TH_LOW)
    bow_ratio: float = 0.75  # best / second-best distance ratio of the bag-of-words matching
    check_orientation: bool = True  # keep only matches in the 3 dominant rotation-histogram bins
    ransac: PnpRansacConfig = field(default_factory=PnpRansacConfig)
    min_pose_inliers: int = 10  # inliers after the first pose optimisation, else the candidate is dropped
    coarse_radius: float = 10.0  # guided search window (pixels at level 0, x the predicted level's scale)
    coarse_max_distance: int = 100  # Hamming bits, guided search in the coarse window (ORB-SLAM's TH_HIGH)
    narrow_radius: float = 3.0  # the second guided search's window, same units
    narrow_max_distance: int = 64  # Hamming bits, the narrow guided search
    narrow_min_inliers: int = 30  # more inliers than this (but fewer than min_inliers) try the narrow search
    min_inliers: int = 50  # inliers that accept a relocalisation
    # Not ORB-SLAM's: a pose the inliers pin down this loosely is refused. The ratio is the camera
    # centre's largest standard deviation (``pose_optimizer.position_sigma``: pixel noise only, the
    # rotation marginalised) over the inliers' median depth. Views of far points on one surface
    # trade sideways motion for rotation, and there a 50-inlier pose can be metres off
    # (benchmarks/saved_maps.md). None: no such check.
    max_position_sigma_ratio: float | None = None
    # Not ORB-SLAM's either, which takes any relocalisation: in localisation mode, a frame on visual
    # odometry relocalises only near its odometry pose, within vo_agreement_m + vo_agreement_per_m x
    # the path travelled on odometry since the map was last tracked, and within vo_agreement_deg +
    # vo_agreement_deg_per_m x that path. Depth errors of far or grazing points that several
    # keyframes share can put a 50-100-inlier relocalisation metres off, where stereo or RGB-D
    # odometry drifts by a few percent of its path (benchmarks/saved_maps.md). A frame that lost its
    # odometry too relocalises anywhere. None: no such check.
    vo_agreement_m: float | None = 0.3  # metres
    vo_agreement_per_m: float = 0.1  # metres per metre travelled on odometry
    vo_agreement_deg: float = 10.0  # degrees
    vo_agreement_deg_per_m: float = 2.0  # degrees per metre travelled on odometry
    # For one second of frames after a relocalisation (ORB-SLAM's mMaxFrames = the camera rate),
    # local-map tracking needs this many inliers, as ORB-SLAM.
    min_local_map_inliers_after: int = 50
    # ORB-SLAM also makes no keyframe in that second, so that a wrong relocalisation does not spread
    # into the map. With stereo/RGB-D depths and min_inliers matches a relocalisation is rarely
    # wrong, and a keyframe at once is worth more: local BA refines the relocalised pose, which
    # rests on points the old map saw from farther away, and the keyframe adds close points.
    pause_keyframes: bool = False  # True: ORB-SLAM's second without keyframes

    def __post_init__(self) -> None:
        problems = [
            f"{name}={getattr(self, name)} must be at least 1"
            for name in ("max_candidates", "min_bow_matches", "min_inliers", "min_pose_inliers")
            if getattr(self, name) < 1
        ]
        if self.max_position_sigma_ratio is not None and not self.max_position_sigma_ratio > 0:
            problems.append(f"max_position_sigma_ratio={self.max_position_sigma_ratio} must be > 0 (or null: no check)")
        if self.max_neighbours < 0:
            problems.append(f"max_neighbours={self.max_neighbours} must be >= 0")
        if self.vo_agreement_m is not None and not self.vo_agreement_m >= 0:
            problems.append(f"vo_agreement_m={self.vo_agreement_m} must be >= 0 metres (or null: no check)")
        problems += [
            f"{name}={getattr(self, name)} must be >= 0"
            for name in ("vo_agreement_per_m", "vo_agreement_deg", "vo_agreement_deg_per_m")
            if not getattr(self, name) >= 0
        ]
        if problems:
            raise ConfigError("invalid frontend tracking.relocalisation configuration: " + "; ".join(problems))


@dataclass(frozen=True)
class PosePrior:
    """Where an independent estimate (visual odometry) puts the frame, and how far from it a
    relocalisation may lie to be believed."""

    T_cam_world: np.ndarray  # (4, 4) maps world points into the camera frame
    max_distance_m: float  # between the camera centres
    max_angle_deg: float  # of the relative rotation

    def offset(self, T_cam_world: np.ndarray) -> tuple[float, float]:
        """(distance m, angle deg) of the pose ``T_cam_world`` from the prior's."""
        return pose_offset(self.T_cam_world, T_cam_world)

    def admits(self, T_cam_world: np.ndarray) -> bool:
        distance, angle = self.offset(T_cam_world)
        return distance <= self.max_distance_m and angle <= self.max_angle_deg


def pose_offset(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Distance (m) between the camera centres of two T_cam_world poses and the angle (deg) of their
    relative rotation."""
    centre_a = -T_a[:3, :3].T @ T_a[:3, 3]
    centre_b = -T_b[:3, :3].T @ T_b[:3, 3]
    cos = (np.trace(T_a[:3, :3] @ T_b[:3, :3].T) - 1.0) / 2.0
    return float(np.linalg.norm(centre_a - centre_b)), math.degrees(math.acos(min(1.0, max(-1.0, cos))))


@dataclass(frozen=True)
class Relocalisation:
    """A lost frame placed in the map."""

    keyframe_id: int  # the candidate keyframe it was matched to
    T_cam_world: np.ndarray  # (4, 4) maps world points into the camera frame
    point_ids: np.ndarray  # (N,) int64 map point of each frame keypoint (inlier matches), -1 none
    n_inliers: int
    n_bow_matches: int  # bag-of-words matches with that keyframe
    candidates_tried: int  # candidates examined, that one included


class _PointTable:
    """The reply's points, looked up by id (ids ascending, as the backend sends them)."""

    def __init__(self, points: MapPoints) -> None:
        self.points = points
        self._order = np.argsort(points.ids, kind="stable")
        self._sorted = np.asarray(points.ids, dtype=np.int64)[self._order]

    def rows(self, point_ids: np.ndarray) -> np.ndarray:
        """(K,) int64 row of each id in the reply's points, -1 for negative or absent ids."""
        ids = np.asarray(point_ids, dtype=np.int64)
        out = np.full(len(ids), -1, dtype=np.int64)
        if len(self._sorted) == 0:
            return out
        pos = np.minimum(np.searchsorted(self._sorted, ids), len(self._sorted) - 1)
        found = (ids >= 0) & (self._sorted[pos] == ids)
        out[found] = self._order[pos[found]]
        return out


def relocalise(
    frame: Frame,
    candidates: RelocalisationCandidates,
    vocabulary: BowTransform,
    config: RelocalisationConfig | None = None,
    pose_config: PoseOptimizerConfig | None = None,
    frame_feature_vector: Any = None,
    prior: PosePrior | None = None,
) -> Relocalisation | None:
    """Place ``frame`` against ``candidates`` (tried best first); None when no candidate holds.

    ``frame_feature_vector``: the frame's ``FeatureVector`` from ``vocabulary.transform`` when the
    caller already has it (it computed the bag of words for the query).
    ``prior``: a candidate's pose it does not admit is refused, and the next candidate tried.
    """
    config = config or RelocalisationConfig()
    pose_config = pose_config or PoseOptimizerConfig()
    if len(frame.features) == 0 or not candidates.candidates:
        return None
    fvec = frame_feature_vector if frame_feature_vector is not None else vocabulary.transform(frame.features.descriptors)[1]
    table = _PointTable(candidates.points)
    for tried, candidate in enumerate(candidates.candidates[: config.max_candidates], start=1):
        keyframe = candidates.keyframe(candidate.keyframe_id)
        if keyframe is None:
            continue
        found = _try_keyframe(frame, fvec, keyframe, table, vocabulary, config, pose_config)
        if found is not None and prior is not None and not prior.admits(found[0]):
            distance, angle = prior.offset(found[0])
            logger.info(
                "frame %d: relocalisation on keyframe %d refused, %.2f m and %.1f deg from the frame's odometry pose (allowed %.2f m, %.1f deg)",
                frame.index, keyframe.id, distance, angle, prior.max_distance_m, prior.max_angle_deg,
            )  # fmt: skip
            continue
        if found is not None:
            T, rows, n_inliers, n_bow = found
            point_ids = np.where(rows >= 0, np.asarray(candidates.points.ids, dtype=np.int64)[np.maximum(rows, 0)], -1)
            logger.debug("relocalised on keyframe %d: %d inliers from %d bag-of-words matches", keyframe.id, n_inliers, n_bow)
            return Relocalisation(int(keyframe.id), T, point_ids.astype(np.int64), n_inliers, n_bow, tried)
    return None


def _try_keyframe(frame, fvec, keyframe: MapKeyframe, table: _PointTable, vocabulary, config, pose_config):
    """(T_cam_world, point rows per frame keypoint (-1 none), inliers, bow matches) or None."""
    kf_rows = table.rows(keyframe.map_point_ids)
    usable = kf_rows >= 0
    if np.count_nonzero(usable) < config.min_bow_matches:
        return None
    _, kf_fvec = vocabulary.transform(keyframe.descriptors)
    feats = frame.features
    idx_kf, idx_frame = search_by_bow(
        kf_fvec, keyframe.descriptors, keyframe.angles_deg, fvec, feats.descriptors, feats.angle_deg,
        usable_a=usable, max_distance=config.bow_max_distance, ratio=config.bow_ratio,
        check_orientation=config.check_orientation,
    )  # fmt: skip
    n_bow = len(idx_kf)
    if n_bow < config.min_bow_matches:
        return None
    rows = np.full(len(feats), -1, dtype=np.int64)
    rows[idx_frame] = kf_rows[idx_kf]
    matched = np.flatnonzero(rows >= 0)
    points = table.points
    ransac = pnp_ransac(
        points.p_world[rows[matched]], feats.px[matched], feats.level_sigma2[feats.level[matched]], frame.calibration, config.ransac
    )
    if ransac is None:
        return None
    rows[matched[~ransac.inliers]] = -1
    found_rows = rows[rows >= 0].copy()  # ORB-SLAM's sFound: not searched again by projection
    T, inliers, n_good = _optimise(frame, ransac.T_cam_world, rows, points, pose_config)
    if n_good < config.min_pose_inliers:
        return None
    rows = np.where(inliers, rows, -1)
    if n_good < config.min_inliers:
        added = _search_keyframe_points(frame, T, keyframe, kf_rows, rows, found_rows, points, config.coarse_radius, config.coarse_max_distance, config)
        if n_good + added >= config.min_inliers:
            T, inliers, n_good = _optimise(frame, T, rows, points, pose_config)
            if config.narrow_min_inliers < n_good < config.min_inliers:
                added = _search_keyframe_points(frame, T, keyframe, kf_rows, rows, rows[rows >= 0], points, config.narrow_radius, config.narrow_max_distance, config)
                if n_good + added >= config.min_inliers:
                    T, inliers, n_good = _optimise(frame, T, rows, points, pose_config)
            rows = np.where(inliers, rows, -1)  # matches added after the last optimisation go too
    if n_good < config.min_inliers or not _pinned_down(frame, T, rows, points, config):
        return None
    return T, rows, n_good, n_bow


def _pinned_down(frame: Frame, T: np.ndarray, rows: np.ndarray, points: MapPoints, config: RelocalisationConfig) -> bool:
    """True when the pose ``T`` is fixed well enough by the inlier matches ``rows`` (-1 none) to be
    accepted: ``config.max_position_sigma_ratio`` unset, or the centre's sigma within it."""
    if config.max_position_sigma_ratio is None:
        return True
    kps = np.flatnonzero(rows >= 0)
    p_world = points.p_world[rows[kps]]
    sigma = frame_position_sigma(frame, T, kps, p_world)
    depth = float(np.median(p_world @ T[2, :3] + T[2, 3]))
    ratio = sigma / depth if depth > 0 else float("inf")
    if ratio > config.max_position_sigma_ratio:
        logger.debug("relocalisation refused: centre sigma %.3f m is %.2f%% of the median depth %.2f m", sigma, 100 * ratio, depth)
        return False
    return True


def _optimise(frame: Frame, T_init: np.ndarray, rows: np.ndarray, points: MapPoints, pose_config: PoseOptimizerConfig):
    """Pose optimisation of the frame's keypoints matched to point ``rows`` (N,) -1 none:
    (T_cam_world, inlier mask (N,), inlier count)."""
    kps = np.flatnonzero(rows >= 0)
    result = optimize_frame_pose(frame, T_init, kps, points.p_world[rows[kps]], pose_config)
    inliers = np.zeros(len(rows), dtype=bool)
    inliers[kps] = result.inliers
    return result.T_cam_world, inliers, int(np.count_nonzero(inliers))


def _search_keyframe_points(frame, T, keyframe: MapKeyframe, kf_rows, rows, found_rows, points: MapPoints, radius, max_distance, config) -> int:
    """ORB-SLAM's ``SearchByProjection(Frame, KeyFrame, sFound, th, ORBdist)``: the keyframe's points
    not in ``found_rows`` nor matched, projected with ``T`` and matched to free keypoints of the
    frame; fills ``rows`` in place and returns how many were added."""
    feats = frame.features
    kf_kps = np.flatnonzero(kf_rows >= 0)
    kf_kps = kf_kps[~np.isin(kf_rows[kf_kps], found_rows) & ~np.isin(kf_rows[kf_kps], rows[rows >= 0])]
    if len(kf_kps) == 0:
        return 0
    cand = kf_rows[kf_kps]
    scales = feats.scale_factors
    proj = project_in_frustum(
        T, points.p_world[cand], points.normals[cand], points.min_distance_m[cand], points.max_distance_m[cand],
        frame.calibration, float(scales[1]) if len(scales) > 1 else 1.0, len(scales), min_view_cos=-2.0,
    )  # fmt: skip
    visible = np.flatnonzero(proj.visible)
    if len(visible) == 0:
        return 0
    level = proj.level[visible]
    match = search_by_projection(
        proj.px[visible], level, points.descriptors[cand[visible]], feats.px, feats.level, feats.descriptors,
        radius * scales[level], max_distance=max_distance, ratio=None, already_matched=rows >= 0,
        min_level_offset=-1, max_level_offset=1,
    )  # fmt: skip
    hit = np.flatnonzero(match >= 0)
    matched_kps = match[hit].astype(np.int64)
    source = visible[hit]
    if config.check_orientation and len(matched_kps):
        keep = rotation_consistent(keyframe.angles_deg[kf_kps[source]] - feats.angle_deg[matched_kps])
        matched_kps, source = matched_kps[keep], source[keep]
    rows[matched_kps] = cand[source]
    return len(matched_kps)


def keyframes_to_restore(candidates: RelocalisationCandidates, keyframe_id: int) -> list[KeyFrame]:
    """The keyframes of ``candidates`` to bring into the frontend's cache after relocalising on
    ``keyframe_id``: that keyframe and its covisible neighbours listed with it, ids ascending."""
    group = next((c for c in candidates.candidates if c.keyframe_id == keyframe_id), None)
    ids = {int(keyframe_id)} | (set(np.asarray(group.neighbour_ids, dtype=np.int64).tolist()) if group is not None else set())
    listed = (candidates.keyframe(i) for i in sorted(ids))
    return [as_keyframe(kf) for kf in listed if kf is not None]


def as_keyframe(keyframe: MapKeyframe) -> KeyFrame:
    """The frontend's KeyFrame of a keyframe of the backend's map: its keypoints and point links,
    no new points (they exist already), frame index -1 (unknown here)."""
    scales = np.asarray(keyframe.scale_factors, dtype=np.float64)
    n = len(keyframe.keypoints_px)
    features = Features(
        px=np.asarray(keyframe.keypoints_px, dtype=np.float32),
        level=np.asarray(keyframe.levels, dtype=np.int16),
        angle_deg=np.asarray(keyframe.angles_deg, dtype=np.float32),
        response=np.zeros(n, dtype=np.float32),
        descriptors=np.asarray(keyframe.descriptors, dtype=np.uint8),
        scale_factors=scales,
        inv_level_sigma2=1.0 / scales**2,
    )
    return KeyFrame(
        id=int(keyframe.id),
        frame_index=-1,
        stamp_ns=int(keyframe.stamp_ns),
        T_world_cam=np.asarray(keyframe.T_world_cam, dtype=float),
        features=features,
        right_u=np.asarray(keyframe.right_u, dtype=np.float32),
        depth_m=np.asarray(keyframe.depth_m, dtype=np.float32),
        map_point_ids=np.asarray(keyframe.map_point_ids, dtype=np.int64),
        new_point_ids=np.zeros(0, dtype=np.int64),
        new_point_keypoints=np.zeros(0, dtype=np.int64),
        new_points_world=np.zeros((0, 3)),
    )
