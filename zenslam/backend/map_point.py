"""A backend map point and ORB-SLAM's frustum test of map points in a keyframe."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.backend.keyframe import BackendKeyframe
from zenslam.backend.point_store import PointStore
from zenslam.map_point_rules import frustum_verdict


class MapPoint:
    """A 3D point with its keyframe observations (keyframe id -> keypoint index).

    Its position, descriptor, viewing direction and distance range live in a row of the map's
    ``PointStore``; the attributes read and write that row (reading an array gives a view of it).
    A point removed from the map keeps its row, which nothing else writes any more."""

    __slots__ = (
        "id", "first_keyframe_id", "created_serial", "observations", "n_visible", "n_found", "weighted_observations",
        "_store", "row",
    )  # fmt: skip

    def __init__(self, point_id: int, store: PointStore, row: int, first_keyframe_id: int, created_serial: int) -> None:
        self.id = int(point_id)
        self.first_keyframe_id = int(first_keyframe_id)  # the keyframe at which the point was created
        self.created_serial = int(created_serial)  # serial of the newest keyframe in the map when the point was created
        self.observations: dict[int, int] = {}
        self.n_visible = 1  # keyframes whose frustum held the point (counted by the backend)
        self.n_found = 1  # keyframes that observed it among those
        self.weighted_observations = 0  # ORB-SLAM's Observations(): a stereo/RGB-D observation counts 2
        self._store = store
        self.row = int(row)  # the point's row in the map's ``PointStore`` (set by the map)

    def __repr__(self) -> str:
        return f"MapPoint(id={self.id}, p_world={self.p_world.tolist()}, observations={self.observations})"

    @property
    def p_world(self) -> np.ndarray:
        """(3,) metres, world frame."""
        return self._store.p_world[self.row]

    @p_world.setter
    def p_world(self, value: np.ndarray) -> None:
        self._store.p_world[self.row] = value

    @property
    def descriptor(self) -> np.ndarray:
        """(32,) uint8 representative descriptor."""
        return self._store.descriptor[self.row]

    @descriptor.setter
    def descriptor(self, value: np.ndarray) -> None:
        self._store.descriptor[self.row] = value

    @property
    def normal(self) -> np.ndarray:
        """(3,) mean viewing direction, world frame."""
        return self._store.normal[self.row]

    @normal.setter
    def normal(self, value: np.ndarray) -> None:
        self._store.normal[self.row] = value

    @property
    def min_distance_m(self) -> float:
        """Scale-invariance range minimum, metres."""
        return float(self._store.min_distance_m[self.row])

    @min_distance_m.setter
    def min_distance_m(self, value: float) -> None:
        self._store.min_distance_m[self.row] = value

    @property
    def max_distance_m(self) -> float:
        """Scale-invariance range maximum, metres."""
        return float(self._store.max_distance_m[self.row])

    @max_distance_m.setter
    def max_distance_m(self, value: float) -> None:
        self._store.max_distance_m[self.row] = value

    def move_to(self, store: PointStore, row: int) -> None:
        """Read and write ``row`` of ``store`` from now on (the map compacting its store)."""
        self._store, self.row = store, int(row)

    def found_ratio(self) -> float:
        """Found / visible."""
        return self.n_found / max(self.n_visible, 1)

    @property
    def reference_keyframe_id(self) -> int | None:
        """The keyframe the point's position is tied to (ORB-SLAM's reference keyframe): the one that
        created it while it still observes it, else the observer with the smallest id; None unobserved.
        Corrections of keyframe poses (loop closing, global BA) move a point with this keyframe."""
        if self.first_keyframe_id in self.observations:
            return self.first_keyframe_id
        return min(self.observations) if self.observations else None


@dataclass(frozen=True)
class PointGeometry:
    """Position, viewing direction and scale-invariance range of M points, as arrays."""

    p_world: np.ndarray  # (M, 3) metres, world frame
    normals: np.ndarray  # (M, 3) mean viewing directions, world frame
    min_distance_m: np.ndarray  # (M,) metres
    max_distance_m: np.ndarray  # (M,) metres

    @classmethod
    def of(cls, points: list[MapPoint]) -> PointGeometry:
        """The arrays of ``points``, in order."""
        stores = {id(pt._store) for pt in points}
        if len(stores) == 1:
            return cls.at(points[0]._store, np.fromiter((pt.row for pt in points), dtype=np.int64, count=len(points)))
        return cls(
            np.array([pt.p_world for pt in points], dtype=float).reshape(-1, 3),
            np.array([pt.normal for pt in points], dtype=float).reshape(-1, 3),
            np.array([pt.min_distance_m for pt in points], dtype=float),
            np.array([pt.max_distance_m for pt in points], dtype=float),
        )

    @classmethod
    def at(cls, store: PointStore, rows: np.ndarray) -> PointGeometry:
        """The arrays of the points in ``rows`` of ``store`` (copies), in order."""
        return cls(
            np.take(store.p_world, rows, axis=0), np.take(store.normal, rows, axis=0),
            np.take(store.min_distance_m, rows), np.take(store.max_distance_m, rows),
        )  # fmt: skip

    def take(self, rows: np.ndarray) -> PointGeometry:
        """The points at ``rows``, in that order."""
        return PointGeometry(
            np.take(self.p_world, rows, axis=0), np.take(self.normals, rows, axis=0),
            np.take(self.min_distance_m, rows), np.take(self.max_distance_m, rows),
        )  # fmt: skip


@dataclass(frozen=True)
class FrustumProjection:
    """Points projected into a keyframe with ORB-SLAM's frustum verdict (``isInFrustum``)."""

    visible: np.ndarray  # (M,) bool: in front, in the image, within the distance range, viewing angle ok
    px: np.ndarray  # (M, 2) pixels
    right_u: np.ndarray  # (M,) right-image u, pixels (nan for mono)
    depth_m: np.ndarray  # (M,) z in the camera, metres
    distance_m: np.ndarray  # (M,) distance to the camera centre, metres
    level: np.ndarray  # (M,) int64 predicted pyramid level


def frustum_projection(
    kf: BackendKeyframe, points: list[MapPoint] | PointGeometry, min_view_cos: float = 0.5
) -> FrustumProjection:
    """Project map points into ``kf`` and test their visibility (``map_point_rules.frustum_verdict``:
    z > 0, inside the image, the distance within [0.8 min, 1.2 max] of the point's scale-invariance
    range and the viewing ray within acos(min_view_cos) of its mean viewing direction)."""
    geometry = points if isinstance(points, PointGeometry) else PointGeometry.of(points)
    p, hi = geometry.p_world, geometry.max_distance_m
    px, right_u, z = kf.project(p)
    verdict = frustum_verdict(
        p, kf.centre_world, z, px, geometry.normals, geometry.min_distance_m, hi, kf.calibration, kf.scale_factor,
        kf.n_levels, min_view_cos,
    )  # fmt: skip
    return FrustumProjection(verdict.visible, px, right_u, z, verdict.distance_m, verdict.level)
