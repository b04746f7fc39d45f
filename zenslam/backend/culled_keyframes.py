"""Where culled keyframes are now: each one kept relative to its spanning-tree parent (ORB-SLAM's Tcp).

Keyframe culling removes a keyframe from the map, but frames tracked against it still name it as
their reference. ORB-SLAM keeps, for a culled keyframe, its pose relative to its parent at the time
of culling and, when it saves the trajectory, follows the parents until a keyframe still in the map:
later corrections of the map (local BA, loop closing, global BA) reach the culled keyframe, and
through it every frame that referred to it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from zenslam.geometry import invert_T


@dataclass(frozen=True)
class CulledKeyframe:
    stamp_ns: int
    parent_id: int  # the spanning-tree parent when the keyframe was culled
    T_parent_cam: np.ndarray  # (4, 4) the keyframe's camera in its parent's frame then


class CulledKeyframes:
    """Culled keyframes by id, each relative to its parent at culling."""

    def __init__(self) -> None:
        self._by_id: dict[int, CulledKeyframe] = {}

    def __len__(self) -> int:
        return len(self._by_id)

    def record(self, kf_id: int, stamp_ns: int, parent_id: int, T_world_parent: np.ndarray, T_world_cam: np.ndarray) -> None:
        """Keep ``kf_id`` relative to ``parent_id`` as the two are now."""
        T_parent_cam = invert_T(np.asarray(T_world_parent, dtype=float)) @ np.asarray(T_world_cam, dtype=float)
        self._by_id[int(kf_id)] = CulledKeyframe(int(stamp_ns), int(parent_id), T_parent_cam)

    def entries(self) -> list[tuple[int, CulledKeyframe]]:
        """(id, entry) of every culled keyframe, ids ascending."""
        return sorted(self._by_id.items())

    def restore(self, kf_id: int, entry: CulledKeyframe) -> None:
        """Put back an entry of a saved map."""
        self._by_id[int(kf_id)] = entry

    def poses(self, in_map: Mapping[int, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ids (C,), stamps (C,), T_world_cam (C, 4, 4)) of every culled keyframe, ids ascending: its
        parent's pose now (``in_map``: poses of the keyframes in the map, by id; a culled parent's
        own pose found the same way) times its pose relative to the parent."""
        resolved: dict[int, np.ndarray] = {}

        def pose(kf_id: int) -> np.ndarray:
            chain = []
            while kf_id not in in_map and kf_id not in resolved:
                chain.append(kf_id)
                kf_id = self._by_id[kf_id].parent_id
            T = in_map[kf_id] if kf_id in in_map else resolved[kf_id]
            for culled in reversed(chain):
                T = T @ self._by_id[culled].T_parent_cam
                resolved[culled] = T
            return T

        ids = sorted(self._by_id)
        stamps = np.array([self._by_id[k].stamp_ns for k in ids], dtype=np.int64)
        T = np.array([pose(k) for k in ids], dtype=float).reshape(-1, 4, 4)
        return np.array(ids, dtype=np.int64), stamps, T
