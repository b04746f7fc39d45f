"""The backend's answer to a lost frontend: candidate places from the keyframe database, with the map data to match them.

The keyframe database ranks the whole map's keyframes against the lost frame's bag of words
(ORB-SLAM's ``DetectRelocalizationCandidates``); the best ``max_candidates`` are sent, each with its
``max_neighbours`` best covisible keyframes (the tracking window the frontend resumes in), every
listed keyframe's keypoints and associations once, and every point they observe once. The
frontend matches the frame against the candidates and puts the matched one's group back into its
cache, so the reply must not depend on what that cache holds.
"""

from __future__ import annotations

import numpy as np

from zenslam.backend.keyframe_database import Candidate, KeyframeDatabase, Score
from zenslam.backend.map import BackendKeyframe, BackendMap
from zenslam.schemas.relocalisation import (
    MapKeyframe,
    MapPoints,
    RelocalisationCandidate,
    RelocalisationCandidates,
    RelocalisationQuery,
)
from zenslam.vocabulary import BowVector


def relocalisation_reply(
    bmap: BackendMap, database: KeyframeDatabase, score: Score, query: RelocalisationQuery, keyframes_processed: int = 0
) -> RelocalisationCandidates:
    """Up to ``query.max_candidates`` candidate keyframes for the query's bag of words, best first,
    with their neighbours and points (see the module doc); no candidate when the words match none.
    A query naming ``window_keyframe_id`` gets that keyframe as the one candidate (none when it is
    not in the map), with its neighbours and points."""
    if query.window_keyframe_id >= 0:  # the window around one keyframe: no ranking
        found = [Candidate(int(query.window_keyframe_id), 0.0, 0.0)] if query.window_keyframe_id in bmap.keyframes else []
    else:
        bow = BowVector(np.asarray(query.word_ids, dtype=np.int64), np.asarray(query.weights, dtype=np.float64))
        found = [c for c in database.relocalisation_candidates(bow, bmap.covisibility, score) if c.keyframe_id in bmap.keyframes]
    candidates = tuple(
        RelocalisationCandidate(
            keyframe_id=int(c.keyframe_id),
            score=float(c.accumulated_score),
            neighbour_ids=np.asarray(bmap.covisibility.best_covisible(c.keyframe_id, query.max_neighbours), dtype=np.int64),
        )
        for c in found[: query.max_candidates]
    )
    listed = sorted({c.keyframe_id for c in candidates} | {int(k) for c in candidates for k in c.neighbour_ids})
    keyframes = tuple(_map_keyframe(bmap.keyframes[k]) for k in listed)
    return RelocalisationCandidates(
        stamp_ns=int(query.stamp_ns),
        candidates=candidates,
        keyframes=keyframes,
        points=_points(bmap, keyframes),
        keyframes_processed=int(keyframes_processed),
    )


def _map_keyframe(kf: BackendKeyframe) -> MapKeyframe:
    return MapKeyframe(
        id=int(kf.id),
        stamp_ns=int(kf.stamp_ns),
        T_world_cam=np.asarray(kf.T_world_cam, dtype=float).copy(),
        keypoints_px=np.asarray(kf.keypoints_px, dtype=np.float32),
        levels=np.asarray(kf.levels, dtype=np.int16),
        angles_deg=np.asarray(kf.angles_deg, dtype=np.float32),
        right_u=np.asarray(kf.right_u, dtype=np.float32),
        depth_m=np.asarray(kf.depth_m, dtype=np.float32),
        descriptors=np.asarray(kf.descriptors, dtype=np.uint8),
        map_point_ids=np.asarray(kf.map_point_ids, dtype=np.int64).copy(),
        scale_factors=np.asarray(kf.scale_factors, dtype=np.float64),
    )


def _points(bmap: BackendMap, keyframes: tuple[MapKeyframe, ...]) -> MapPoints:
    """The map points the keyframes observe, ids ascending."""
    observed = np.concatenate([kf.map_point_ids for kf in keyframes]) if keyframes else np.zeros(0, dtype=np.int64)
    ids = [p for p in np.unique(observed[observed >= 0]).tolist() if p in bmap.points]
    points = [bmap.points[p] for p in ids]
    return MapPoints(
        ids=np.asarray(ids, dtype=np.int64),
        p_world=np.array([p.p_world for p in points], dtype=float).reshape(-1, 3),
        descriptors=np.array([p.descriptor for p in points], dtype=np.uint8).reshape(-1, 32),
        normals=np.array([p.normal for p in points], dtype=float).reshape(-1, 3),
        min_distance_m=np.array([p.min_distance_m for p in points], dtype=float),
        max_distance_m=np.array([p.max_distance_m for p in points], dtype=float),
    )
