"""The local window of a frame in the map cache: ORB-SLAM's local keyframes (``UpdateLocalKeyFrames``)
and local points (``UpdateLocalPoints``), which local-map tracking searches and eviction keeps."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.frontend.local_map import LocalMap


@dataclass(frozen=True)
class LocalWindow:
    """The keyframes around the current frame (slots into the map) and the reference among them."""

    keyframe_slots: np.ndarray  # (L,) int64, the ones voted for first (most shared points first)
    reference_slot: int  # the keyframe sharing most points with the frame, -1 if none


def local_window(local_map: LocalMap, frame_point_rows: np.ndarray) -> LocalWindow:
    """ORB-SLAM's ``UpdateLocalKeyFrames`` for a frame matched to ``frame_point_rows`` (-1 none).

    Every keyframe observing a matched point is local; then, while there are at most
    ``max_local_keyframes``, each of those adds its first not-yet-local keyframe among its
    ``best_covisible`` best covisible ones, one child and its parent (``LocalMapConfig``). The voted
    keyframes are visited by decreasing vote (ORB-SLAM's order is by pointer, i.e. arbitrary) and
    ORB-SLAM2's early exit after adding a parent is not reproduced.
    """
    config = local_map.config
    rows = np.asarray(frame_point_rows, dtype=np.int64)
    rows = rows[rows >= 0]
    rows = rows[local_map.valid[rows]]
    if len(rows) == 0 or local_map.n_slots == 0:
        return LocalWindow(np.zeros(0, dtype=np.int64), -1)
    in_frame = np.zeros(local_map.n_points, dtype=bool)
    in_frame[rows] = True
    obs_rows, obs_slots, _ = local_map.observation_arrays()
    votes = np.bincount(obs_slots[in_frame[obs_rows]], minlength=local_map.n_slots)
    voted = np.flatnonzero(votes)
    if len(voted) == 0:
        return LocalWindow(np.zeros(0, dtype=np.int64), -1)
    voted = voted[np.lexsort((voted, -votes[voted]))]
    selected = [int(s) for s in voted]
    included = set(selected)
    for slot in voted.tolist():
        if len(selected) > config.max_local_keyframes:
            break
        parent = local_map.parent(slot)
        candidates = (local_map.best_covisible(slot, config.best_covisible), local_map.children(slot), [parent] if parent >= 0 else [])
        for group in candidates:
            for other in group:
                if other not in included:
                    selected.append(other)
                    included.add(other)
                    break
    return LocalWindow(np.asarray(selected, dtype=np.int64), int(voted[0]))


def local_point_rows(local_map: LocalMap, keyframe_slots: np.ndarray) -> np.ndarray:
    """ORB-SLAM's ``UpdateLocalPoints``: sorted unique rows of valid points seen by the keyframes."""
    if len(keyframe_slots) == 0:
        return np.zeros(0, dtype=np.int64)
    seen = np.zeros(local_map.n_points, dtype=bool)
    for slot in keyframe_slots:
        seen[local_map.keyframe_point_rows(int(slot))] = True
    return np.flatnonzero(seen & local_map.valid)
