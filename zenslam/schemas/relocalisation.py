"""The backend/relocalisation query: a lost frame's bag of words in, candidate places of the map out.

A lost frontend sends the frame's bag-of-words vector; the backend answers with up to
``max_candidates`` keyframes of its keyframe database (ORB-SLAM's relocalisation candidates, best
first), each with its ``max_neighbours`` best covisible keyframes, and the data the frontend needs
to match the frame against them and to resume tracking there: every listed keyframe's keypoints
and point associations once, and the points they observe once. The frontend may have evicted all
of it from its cache (or never held it): the reply is self-contained.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def _empty(shape: tuple[int, ...], dtype: type) -> np.ndarray:
    return np.zeros(shape, dtype=dtype)


@dataclass(frozen=True)
class RelocalisationQuery:
    """A lost frame's bag-of-words vector (W words) and how much of the map to send back."""

    stamp_ns: int  # the lost frame's stamp
    word_ids: np.ndarray  # (W,) int64 ascending vocabulary word ids
    weights: np.ndarray  # (W,) float64 TF-IDF weights, L1-normalised
    max_candidates: int = 3  # candidate keyframes wanted, at most
    max_neighbours: int = 10  # covisible neighbours per candidate, at most (strongest first)
    # >= 0: not a lost frame but a request for the window around this keyframe: the reply's one
    # candidate is it (score 0) with its neighbours, whatever the words; -1: rank by the words.
    window_keyframe_id: int = -1

    def __post_init__(self) -> None:
        if np.shape(self.word_ids) != np.shape(self.weights) or np.ndim(self.word_ids) != 1:
            raise ValueError(f"a bag of words needs (W,) word ids and weights, got {np.shape(self.word_ids)} and {np.shape(self.weights)}")


@dataclass(frozen=True)
class MapKeyframe:
    """A keyframe of the backend's map as relocalisation reads it (N keypoints, L pyramid levels)."""

    id: int
    stamp_ns: int
    T_world_cam: np.ndarray  # (4, 4) maps camera coordinates to world
    keypoints_px: np.ndarray  # (N, 2) float32 level-0 pixels
    levels: np.ndarray  # (N,) int16 pyramid level
    angles_deg: np.ndarray  # (N,) float32 keypoint orientation, degrees
    right_u: np.ndarray  # (N,) float32 right-image u, pixels; -1 none
    depth_m: np.ndarray  # (N,) float32 metres; -1 none
    descriptors: np.ndarray  # (N, 32) uint8
    map_point_ids: np.ndarray  # (N,) int64 point each keypoint observes, -1 none
    scale_factors: np.ndarray  # (L,) float64 scale of each pyramid level


@dataclass(frozen=True)
class MapPoints:
    """P map points with what tracking needs of them (the point part of a map update)."""

    ids: np.ndarray = field(default_factory=lambda: _empty((0,), np.int64))  # (P,)
    p_world: np.ndarray = field(default_factory=lambda: _empty((0, 3), np.float64))  # (P, 3) metres, world frame
    descriptors: np.ndarray = field(default_factory=lambda: _empty((0, 32), np.uint8))  # (P, 32) representative
    normals: np.ndarray = field(default_factory=lambda: _empty((0, 3), np.float64))  # (P, 3) mean viewing direction
    min_distance_m: np.ndarray = field(default_factory=lambda: _empty((0,), np.float64))  # (P,) scale invariance
    max_distance_m: np.ndarray = field(default_factory=lambda: _empty((0,), np.float64))  # (P,)

    def __post_init__(self) -> None:
        n = len(self.ids)
        shapes = {
            "p_world": (np.shape(self.p_world), (n, 3)),
            "descriptors": (np.shape(self.descriptors), (n, 32)),
            "normals": (np.shape(self.normals), (n, 3)),
            "min_distance_m": (np.shape(self.min_distance_m), (n,)),
            "max_distance_m": (np.shape(self.max_distance_m), (n,)),
        }
        wrong = {k: got for k, (got, want) in shapes.items() if got != want}
        if wrong:
            raise ValueError(f"MapPoints for {n} points has mis-shaped arrays: {wrong}")


@dataclass(frozen=True)
class RelocalisationCandidate:
    """A place the keyframe database found: a keyframe and its best covisible neighbours."""

    keyframe_id: int
    score: float  # the database's accumulated score of the keyframe's covisibility group
    neighbour_ids: np.ndarray = field(default_factory=lambda: _empty((0,), np.int64))  # (K,) strongest first


@dataclass(frozen=True)
class RelocalisationCandidates:
    """The backend's reply: candidates best first, and each listed keyframe and point once."""

    stamp_ns: int  # the query's stamp
    candidates: tuple[RelocalisationCandidate, ...] = ()
    keyframes: tuple[MapKeyframe, ...] = ()  # every candidate and neighbour, ids ascending
    points: MapPoints = field(default_factory=MapPoints)  # every point those keyframes observe, ids ascending
    keyframes_processed: int = 0  # keyframes the backend had processed when it answered

    def keyframe(self, keyframe_id: int) -> MapKeyframe | None:
        """The listed keyframe ``keyframe_id``, None if absent."""
        return next((kf for kf in self.keyframes if kf.id == keyframe_id), None)
