"""The backend's map: keyframes and map points with their observations, kept consistent with the graphs.

Every change goes through ``BackendMap`` methods, which keep the two sides of each observation
(``MapPoint.observations[kf_id] = keypoint`` and ``BackendKeyframe.map_point_ids[keypoint] =
point id``), the covisibility weights, the spanning tree and the essential graph's loop edges in
step, and record what changed (``MapChanges``) so the local mapper can publish a map update.
Keyframes and points are small objects in dicts: the backend handles a few keyframes per second,
and the per-keyframe work over thousands of points is done on arrays gathered from them.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.backend.culled_keyframes import CulledKeyframes
from zenslam.backend.essential_graph import EssentialGraph
from zenslam.backend.spanning_tree import SpanningTree, choose_parent
from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import ZenslamError
from zenslam.geometry import invert_T, transform_points
from zenslam.map_point_rules import (
    mean_viewing_directions,
    predict_scale_level,
    representative_descriptors,
    scale_invariance_range,
)
from zenslam.schemas.codec import KeyframeMessage
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE

logger = logging.getLogger(__name__)


class MapError(ZenslamError):
    """A map operation names a keyframe, point or keypoint that is unknown or already taken."""


class IdAllocator:
    """Hands out int ids start, start + 1, ... in order."""

    def __init__(self, start: int) -> None:
        self._next = int(start)

    def next(self) -> int:
        """One new id."""
        value = self._next
        self._next += 1
        return value

    @property
    def upcoming(self) -> int:
        """The id ``next`` returns next."""
        return self._next


@dataclass(eq=False)
class BackendKeyframe:
    """A keyframe as the backend keeps it; ``map_point_ids`` (N,) int64 (-1 none) is owned by the map."""

    id: int
    stamp_ns: int
    T_world_cam: np.ndarray  # (4, 4) maps camera coordinates (x right, y down, z forward) to world
    calibration: PinholeCalibration
    sensor: SensorKind
    keypoints_px: np.ndarray  # (N, 2) float64 level-0 pixels
    levels: np.ndarray  # (N,) int64 pyramid level
    angles_deg: np.ndarray  # (N,) float64
    right_u: np.ndarray  # (N,) float64 right-image u, pixels; -1 none
    depth_m: np.ndarray  # (N,) float64 metres; -1 none
    descriptors: np.ndarray  # (N, 32) uint8
    scale_factors: np.ndarray  # (L,) float64, scale_factor**level
    map_point_ids: np.ndarray  # (N,) int64
    serial: int = -1  # insertion order in the map (0 for the first keyframe)

    @classmethod
    def from_message(cls, msg: KeyframeMessage) -> BackendKeyframe:
        """Writable copies of a keyframe message's arrays; associations start empty (all -1)."""
        n = len(msg.keypoints_px)
        return cls(
            id=int(msg.id),
            stamp_ns=int(msg.stamp_ns),
            T_world_cam=np.array(msg.T_world_cam, dtype=float),
            calibration=msg.calibration,
            sensor=msg.sensor,
            keypoints_px=np.array(msg.keypoints_px, dtype=float).reshape(n, 2),
            levels=np.array(msg.levels, dtype=np.int64),
            angles_deg=np.array(msg.angles_deg, dtype=float),
            right_u=np.array(msg.right_u, dtype=float),
            depth_m=np.array(msg.depth_m, dtype=float),
            descriptors=np.array(msg.descriptors, dtype=np.uint8).reshape(n, 32),
            scale_factors=np.array(msg.scale_factors, dtype=float),
            map_point_ids=np.full(n, -1, dtype=np.int64),
        )

    @property
    def n_keypoints(self) -> int:
        """Number of keypoints N."""
        return len(self.keypoints_px)

    @property
    def scale_factor(self) -> float:
        """Scale ratio between consecutive pyramid levels."""
        return float(self.scale_factors[1]) if len(self.scale_factors) > 1 else 1.0

    @property
    def n_levels(self) -> int:
        """Pyramid levels L."""
        return len(self.scale_factors)

    @property
    def level_sigma2(self) -> np.ndarray:
        """(L,) keypoint position variance per level, px^2 (ORB-SLAM: scale_factor**(2 level))."""
        return self.scale_factors**2

    @property
    def T_cam_world(self) -> np.ndarray:
        """The pose as a world -> camera transform (4, 4)."""
        return invert_T(self.T_world_cam)

    @property
    def centre_world(self) -> np.ndarray:
        """Camera centre (3,) metres, world frame."""
        return np.asarray(self.T_world_cam)[:3, 3].copy()

    @property
    def has_right(self) -> np.ndarray:
        """(N,) bool: the keypoint has a right-image coordinate (stereo/RGB-D measurement)."""
        return self.right_u >= 0

    def project(self, p_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixels (M, 2), right-image u (M,) (nan for mono) and depth z (M,) metres of world points (M, 3)."""
        p_cam = transform_points(self.T_cam_world, np.asarray(p_world, dtype=float).reshape(-1, 3))
        z = p_cam[:, 2]
        safe_z = np.where(np.abs(z) > 1e-12, z, 1e-12)
        c = self.calibration
        px = np.column_stack([c.fx * p_cam[:, 0] / safe_z + c.cx, c.fy * p_cam[:, 1] / safe_z + c.cy])
        right_u = px[:, 0] - c.bf / safe_z if c.baseline_m is not None else np.full(len(z), np.nan)
        return px, right_u, z

    def unproject(self, keypoints: np.ndarray) -> np.ndarray:
        """World points (K, 3) metres of keypoints (indices) with a depth, from their pixel and depth."""
        keypoints = np.asarray(keypoints, dtype=np.int64)
        c, z = self.calibration, self.depth_m[keypoints]
        uv = self.keypoints_px[keypoints]
        p_cam = np.column_stack([(uv[:, 0] - c.cx) * z / c.fx, (uv[:, 1] - c.cy) * z / c.fy, z])
        return transform_points(self.T_world_cam, p_cam)


@dataclass(eq=False)
class MapPoint:
    """A 3D point with its keyframe observations (keyframe id -> keypoint index)."""

    id: int
    p_world: np.ndarray  # (3,) metres, world frame
    first_keyframe_id: int  # the keyframe at which the point was created
    created_serial: int  # serial of the newest keyframe in the map when the point was created
    descriptor: np.ndarray = field(default_factory=lambda: np.zeros(32, dtype=np.uint8))  # representative
    normal: np.ndarray = field(default_factory=lambda: np.zeros(3))  # mean viewing direction, world
    min_distance_m: float = 0.0  # scale-invariance range, metres
    max_distance_m: float = float("inf")
    observations: dict[int, int] = field(default_factory=dict)
    n_visible: int = 1  # keyframes whose frustum held the point (counted by the backend)
    n_found: int = 1  # keyframes that observed it among those
    weighted_observations: int = 0  # ORB-SLAM's Observations(): a stereo/RGB-D observation counts 2

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


@dataclass
class MapChanges:
    """What changed in the map since the last ``BackendMap.take_changes``."""

    keyframes: set[int] = field(default_factory=set)  # pose or associations changed
    points: set[int] = field(default_factory=set)  # created, moved, or descriptor/normal/range refreshed
    created_points: set[int] = field(default_factory=set)  # created here with an allocated id
    removed_points: set[int] = field(default_factory=set)
    removed_keyframes: set[int] = field(default_factory=set)


def _group_by_observation_count(points: dict[int, MapPoint], ids: list[int]) -> list[list[int]]:
    """``ids`` split into groups of points with equal observation counts (each group keeps the order)."""
    groups: dict[int, list[int]] = {}
    for point_id in ids:
        groups.setdefault(len(points[point_id].observations), []).append(point_id)
    return [groups[k] for k in sorted(groups)]


@dataclass(frozen=True)
class FrustumProjection:
    """Points projected into a keyframe with ORB-SLAM's frustum verdict (``isInFrustum``)."""

    visible: np.ndarray  # (M,) bool: in front, in the image, within the distance range, viewing angle ok
    px: np.ndarray  # (M, 2) pixels
    right_u: np.ndarray  # (M,) right-image u, pixels (nan for mono)
    depth_m: np.ndarray  # (M,) z in the camera, metres
    distance_m: np.ndarray  # (M,) distance to the camera centre, metres
    level: np.ndarray  # (M,) int64 predicted pyramid level


def frustum_projection(kf: BackendKeyframe, points: list[MapPoint], min_view_cos: float = 0.5) -> FrustumProjection:
    """Project map points into ``kf``: visible when z > 0, inside the image, the distance within
    [0.8 min, 1.2 max] of the point's scale-invariance range and the viewing ray within
    acos(min_view_cos) of its mean viewing direction (ORB-SLAM's margins)."""
    p = np.array([pt.p_world for pt in points], dtype=float).reshape(-1, 3)
    normals = np.array([pt.normal for pt in points], dtype=float).reshape(-1, 3)
    lo = np.array([pt.min_distance_m for pt in points], dtype=float)
    hi = np.array([pt.max_distance_m for pt in points], dtype=float)
    px, right_u, z = kf.project(p)
    rays = p - kf.centre_world
    dist = np.linalg.norm(rays, axis=1)
    view_cos = np.einsum("ij,ij->i", rays, normals) / np.maximum(dist, 1e-12)
    c = kf.calibration
    visible = (
        (z > 0)
        & (px[:, 0] >= 0) & (px[:, 0] < c.width) & (px[:, 1] >= 0) & (px[:, 1] < c.height)
        & (dist >= 0.8 * lo) & (dist <= 1.2 * hi)
        & (view_cos >= min_view_cos)
    )  # fmt: skip
    level = predict_scale_level(dist, hi, kf.scale_factor, kf.n_levels)
    return FrustumProjection(visible, px, right_u, z, dist, level)


class BackendMap:
    """Keyframes, map points and their graphs, changed only through these methods."""

    def __init__(
        self, min_covisibility_weight: int = 15, essential_min_weight: int = 100, point_id_start: int = BACKEND_POINT_ID_BASE
    ) -> None:
        self.keyframes: dict[int, BackendKeyframe] = {}  # in insertion order
        self.points: dict[int, MapPoint] = {}
        self.covisibility = CovisibilityGraph(min_covisibility_weight)
        self.spanning_tree = SpanningTree()
        self.essential_graph = EssentialGraph(self.spanning_tree, self.covisibility, essential_min_weight)
        self.point_id_allocator = IdAllocator(point_id_start)
        self.first_keyframe_id: int | None = None  # the gauge keyframe, never removed
        self.culled = CulledKeyframes()  # removed keyframes, each relative to its parent then
        self.changes = MapChanges()
        self._next_serial = 0
        self._replaced: dict[int, int] = {}  # fused point id -> the id that replaced it
        self._stale_descriptor: set[int] = set()
        self._stale_geometry: set[int] = set()

    # ---- bookkeeping a saved map keeps (``map_file``) ----------------------------------------------
    @property
    def next_serial(self) -> int:
        """The serial the next inserted keyframe gets."""
        return self._next_serial

    def fused_ids(self) -> dict[int, int]:
        """Fused point id -> the id that replaced it (a copy; ``resolve`` follows the chains)."""
        return dict(self._replaced)

    def restore_bookkeeping(self, next_serial: int, fused: dict[int, int], next_point_id: int) -> None:
        """Set the serial and id counters and the fused ids of a map rebuilt from a saved one."""
        self._next_serial = int(next_serial)
        self._replaced = dict(fused)
        self.point_id_allocator = IdAllocator(next_point_id)

    # ---- lookups ---------------------------------------------------------------------------------
    def keyframe(self, kf_id: int) -> BackendKeyframe:
        """The keyframe ``kf_id``; MapError when unknown."""
        kf = self.keyframes.get(kf_id)
        if kf is None:
            raise MapError(f"keyframe {kf_id} is not in the backend map ({len(self.keyframes)} keyframes)")
        return kf

    def point(self, point_id: int) -> MapPoint:
        """The map point ``point_id``; MapError when unknown."""
        pt = self.points.get(point_id)
        if pt is None:
            raise MapError(f"map point {point_id} is not in the backend map")
        return pt

    def resolve(self, point_id: int) -> int:
        """The live id standing for ``point_id`` (following fusions), -1 if it was removed or never known."""
        seen = 0
        while point_id in self._replaced and seen < 1000:
            point_id, seen = self._replaced[point_id], seen + 1
        return point_id if point_id in self.points else -1

    def keyframe_point_ids(self, kf_id: int) -> np.ndarray:
        """Ids (int64) of the points ``kf_id`` observes, in keypoint order."""
        ids = self.keyframe(kf_id).map_point_ids
        return ids[ids >= 0].copy()

    # ---- points ------------------------------------------------------------------------------------
    def add_point(self, point_id: int, p_world: np.ndarray, first_keyframe_id: int) -> MapPoint:
        """A point without observations yet (add them with ``add_observation``)."""
        if point_id in self.points or point_id in self._replaced:
            raise MapError(f"map point id {point_id} is already used; ids are never reused")
        if point_id < 0:
            raise MapError(f"map point ids are non-negative, got {point_id}")
        pt = MapPoint(int(point_id), np.array(p_world, dtype=float).reshape(3), int(first_keyframe_id), self._next_serial - 1)
        self.points[pt.id] = pt
        self.changes.points.add(pt.id)
        return pt

    def new_point(self, p_world: np.ndarray, first_keyframe_id: int) -> MapPoint:
        """A point created by the backend, with the next id of its own id space."""
        pt = self.add_point(self.point_id_allocator.next(), p_world, first_keyframe_id)
        self.changes.created_points.add(pt.id)
        return pt

    def add_observation(self, point_id: int, kf_id: int, keypoint: int) -> None:
        """Keypoint ``keypoint`` of keyframe ``kf_id`` observes point ``point_id``."""
        pt, kf = self.point(point_id), self.keyframe(kf_id)
        if kf_id in pt.observations:
            raise MapError(f"point {point_id} is already observed by keyframe {kf_id} (keypoint {pt.observations[kf_id]})")
        if kf.map_point_ids[keypoint] >= 0:
            raise MapError(f"keypoint {keypoint} of keyframe {kf_id} already observes point {kf.map_point_ids[keypoint]}")
        self.covisibility.add_observation(kf_id, pt.observations.keys())
        pt.observations[kf_id] = int(keypoint)
        pt.weighted_observations += 2 if kf.right_u[keypoint] >= 0 else 1
        kf.map_point_ids[keypoint] = point_id
        self._touch(point_id, kf_id)

    def remove_observation(self, point_id: int, kf_id: int) -> None:
        """Keyframe ``kf_id`` no longer observes point ``point_id`` (the point stays)."""
        pt, kf = self.point(point_id), self.keyframe(kf_id)
        keypoint = pt.observations.pop(kf_id, None)
        if keypoint is None:
            raise MapError(f"point {point_id} is not observed by keyframe {kf_id}")
        pt.weighted_observations -= 2 if kf.right_u[keypoint] >= 0 else 1
        kf.map_point_ids[keypoint] = -1
        self.covisibility.remove_observation(kf_id, pt.observations.keys())
        self._touch(point_id, kf_id)

    def _touch(self, point_id: int, kf_id: int) -> None:
        self._stale_descriptor.add(point_id)
        self._stale_geometry.add(point_id)
        self.changes.keyframes.add(kf_id)
        self.changes.points.add(point_id)

    def remove_point(self, point_id: int) -> None:
        """Delete a point and all its observations."""
        pt = self.point(point_id)
        for kf_id in sorted(pt.observations):
            self.remove_observation(point_id, kf_id)
        del self.points[point_id]
        self._stale_descriptor.discard(point_id)
        self._stale_geometry.discard(point_id)
        self.changes.points.discard(point_id)
        self.changes.removed_points.add(point_id)

    def replace_point(self, old_id: int, new_id: int) -> None:
        """Merge ``old_id`` into ``new_id`` (ORB-SLAM's ``MapPoint::Replace``): each keyframe observing
        old observes new at the same keypoint unless it already observes new; old is deleted."""
        if old_id == new_id:
            return
        old, new = self.point(old_id), self.point(new_id)
        for kf_id, keypoint in sorted(old.observations.items()):
            self.remove_observation(old_id, kf_id)
            if kf_id not in new.observations:
                self.add_observation(new_id, kf_id, keypoint)
        new.n_visible += old.n_visible
        new.n_found += old.n_found
        self.remove_point(old_id)
        self._replaced[old_id] = new_id

    def remove_weak_points(self, point_ids: list[int], min_keyframes: int) -> list[int]:
        """Delete those of ``point_ids`` still in the map but observed by fewer than ``min_keyframes``."""
        weak = sorted({p for p in point_ids if p in self.points and len(self.points[p].observations) < min_keyframes})
        for point_id in weak:
            self.remove_point(point_id)
        return weak

    def set_point_position(self, point_id: int, p_world: np.ndarray) -> None:
        """Move a point (metres, world frame)."""
        self.point(point_id).p_world = np.array(p_world, dtype=float).reshape(3)
        self._stale_geometry.add(point_id)
        self.changes.points.add(point_id)

    def set_point_positions(self, point_ids: list[int], p_world: np.ndarray) -> None:
        """Move points ``point_ids`` to the rows of ``p_world`` (N, 3) (metres, world frame)."""
        rows = np.array(p_world, dtype=float).reshape(len(point_ids), 3)
        for point_id, row in zip(point_ids, rows):
            self.point(point_id).p_world = row
        self._stale_geometry.update(point_ids)
        self.changes.points.update(point_ids)

    # ---- keyframes ---------------------------------------------------------------------------------
    def add_keyframe(self, kf: BackendKeyframe) -> None:
        """Insert a keyframe: its ``map_point_ids`` (existing points, each at most once) become
        observations, covisibility is updated and its spanning-tree parent chosen among the others."""
        if kf.id in self.keyframes or kf.id in self.spanning_tree:
            raise MapError(f"keyframe {kf.id} is already in the backend map; keyframe ids must be unique")
        requested = np.asarray(kf.map_point_ids, dtype=np.int64).copy()
        known = requested[requested >= 0]
        missing = sorted({int(p) for p in known if int(p) not in self.points})
        if missing or len(np.unique(known)) != len(known):
            raise MapError(
                f"keyframe {kf.id} associates unknown points {missing[:5]} or one point twice; resolve ids first"
            )
        older = list(self.keyframes)
        kf.map_point_ids = np.full(kf.n_keypoints, -1, dtype=np.int64)
        kf.serial = self._next_serial
        self._next_serial += 1
        self.keyframes[kf.id] = kf
        self.covisibility.add_keyframe(kf.id)
        for keypoint in np.flatnonzero(requested >= 0).tolist():
            self.add_observation(int(requested[keypoint]), kf.id, keypoint)
        self.spanning_tree.add(kf.id, choose_parent(kf.id, self.covisibility, older))
        if self.first_keyframe_id is None:
            self.first_keyframe_id = kf.id
        self.changes.keyframes.add(kf.id)

    def remove_keyframe(self, kf_id: int) -> list[int]:
        """Delete a keyframe (not the first): its observations, its node in the graphs; its spanning-tree
        children are re-attached; it is kept relative to its parent in ``culled``. Returns the ids of
        the points that lost an observation."""
        if kf_id == self.first_keyframe_id:
            raise MapError(f"keyframe {kf_id} is the first keyframe (the gauge) and is never removed")
        point_ids = self.keyframe_point_ids(kf_id).tolist()
        kf, parent = self.keyframes[kf_id], self.spanning_tree.parent(kf_id)
        if parent is not None:
            self.culled.record(kf_id, kf.stamp_ns, parent, self.keyframes[parent].T_world_cam, kf.T_world_cam)
        for point_id in point_ids:
            self.remove_observation(point_id, kf_id)
        self.covisibility.remove_keyframe(kf_id)
        self.spanning_tree.remove(kf_id, self.covisibility)
        self.essential_graph.remove_keyframe(kf_id)
        del self.keyframes[kf_id]
        self.changes.keyframes.discard(kf_id)
        self.changes.removed_keyframes.add(kf_id)
        return point_ids

    def set_keyframe_pose(self, kf_id: int, T_world_cam: np.ndarray) -> None:
        """Replace a keyframe's pose (camera -> world); its points' viewing directions go stale."""
        kf = self.keyframe(kf_id)
        kf.T_world_cam = np.array(T_world_cam, dtype=float).reshape(4, 4)
        self._stale_geometry.update(self.keyframe_point_ids(kf_id).tolist())
        self.changes.keyframes.add(kf_id)

    # ---- derived point attributes -------------------------------------------------------------------
    def refresh_points(self) -> int:
        """Recompute stale representative descriptors, viewing directions and scale-invariance ranges
        (ORB-SLAM's ComputeDistinctiveDescriptors and UpdateNormalAndDepth). Returns points refreshed."""
        desc_ids = sorted(p for p in self._stale_descriptor if self.points[p].observations)
        geo_ids = sorted(p for p in self._stale_geometry if self.points[p].observations)
        row_of_kf = {k: row for row, k in enumerate(self.keyframes)}
        for ids in _group_by_observation_count(self.points, desc_ids):
            pts = [self.points[p] for p in ids]
            pairs = [(row_of_kf[k], i) for pt in pts for k, i in sorted(pt.observations.items())]
            groups = self._descriptors_at(pairs).reshape(len(pts), -1, 32)
            for pt, descriptor in zip(pts, representative_descriptors(groups)):
                pt.descriptor = descriptor
        if geo_ids:
            centres = np.array([kf.T_world_cam[:3, 3] for kf in self.keyframes.values()], dtype=float)
            for ids in _group_by_observation_count(self.points, geo_ids):
                self._refresh_geometry([self.points[p] for p in ids], row_of_kf, centres)
        self.changes.points.update(desc_ids)
        self.changes.points.update(geo_ids)
        self._stale_descriptor.clear()
        self._stale_geometry.clear()
        return len(set(desc_ids) | set(geo_ids))

    def _descriptors_at(self, pairs: list[tuple[int, int]]) -> np.ndarray:
        """Descriptors (M, 32) uint8 of (keyframe row in insertion order, keypoint) pairs, in order."""
        rows, keypoints = np.array(pairs, dtype=np.int64).reshape(-1, 2).T
        out = np.empty((len(rows), 32), dtype=np.uint8)
        keyframes = list(self.keyframes.values())
        order = np.argsort(rows, kind="stable")
        distinct, starts = np.unique(rows[order], return_index=True)
        for row, sel in zip(distinct.tolist(), np.split(order, starts[1:])):
            out[sel] = keyframes[row].descriptors[keypoints[sel]]
        return out

    def _refresh_geometry(self, pts: list[MapPoint], row_of_kf: dict[int, int], centres: np.ndarray) -> None:
        """Normals and distance ranges of points that all have the same number of observations;
        ``centres`` (K, 3) are the keyframes' centres by row of ``row_of_kf`` (metres, world)."""
        p_world = np.array([pt.p_world for pt in pts])
        observer_rows = np.array([row_of_kf[k] for pt in pts for k in sorted(pt.observations)], dtype=np.int64)
        normals = mean_viewing_directions(p_world, centres[observer_rows.reshape(len(pts), -1)])  # (P, K, 3) observers
        refs = [pt.first_keyframe_id if pt.first_keyframe_id in pt.observations else min(pt.observations) for pt in pts]
        distance = np.linalg.norm(p_world - centres[[row_of_kf[r] for r in refs]], axis=1)
        keypoint = np.array([pt.observations[r] for pt, r in zip(pts, refs)], dtype=np.int64)
        ref_arr = np.array(refs, dtype=np.int64)
        level = np.zeros(len(pts), dtype=np.int64)
        pyramid: dict[tuple[float, int], list[int]] = {}
        order = np.argsort(ref_arr, kind="stable")
        distinct, starts = np.unique(ref_arr[order], return_index=True)
        for r, sel in zip(distinct.tolist(), np.split(order, starts[1:])):
            kf = self.keyframes[r]
            level[sel] = kf.levels[keypoint[sel]]
            pyramid.setdefault((kf.scale_factor, kf.n_levels), []).extend(sel.tolist())
        lo, hi = np.zeros(len(pts)), np.zeros(len(pts))
        for (scale_factor, n_levels), rows in sorted(pyramid.items()):
            sel = np.array(sorted(rows), dtype=np.int64)
            lo[sel], hi[sel] = scale_invariance_range(distance[sel], level[sel], scale_factor, n_levels)
        for k, pt in enumerate(pts):
            pt.normal = normals[k]
            pt.min_distance_m, pt.max_distance_m = float(lo[k]), float(hi[k])

    # ---- change log and checks -----------------------------------------------------------------------
    def take_changes(self) -> MapChanges:
        """What changed since the last call (pending refreshes are applied first); resets the log."""
        self.refresh_points()
        changes, self.changes = self.changes, MapChanges()
        return changes

    def check_consistency(self) -> list[str]:
        """Every broken invariant, described (empty when the map is consistent)."""
        problems: list[str] = []
        for point_id, pt in self.points.items():
            weighted = 0
            for kf_id, keypoint in pt.observations.items():
                kf = self.keyframes.get(kf_id)
                if kf is None or kf.map_point_ids[keypoint] != point_id:
                    problems.append(f"point {point_id} -> keyframe {kf_id} keypoint {keypoint} is not mirrored")
                else:
                    weighted += 2 if kf.right_u[keypoint] >= 0 else 1
            if weighted != pt.weighted_observations:
                problems.append(f"point {point_id} weighted observations {pt.weighted_observations} != {weighted}")
        shared: Counter[tuple[int, int]] = Counter()
        for kf_id, kf in self.keyframes.items():
            for keypoint in np.flatnonzero(kf.map_point_ids >= 0).tolist():
                pt = self.points.get(int(kf.map_point_ids[keypoint]))
                if pt is None or pt.observations.get(kf_id) != keypoint:
                    problems.append(f"keyframe {kf_id} keypoint {keypoint} -> point {kf.map_point_ids[keypoint]} is not mirrored")
        for pt in self.points.values():
            observers = sorted(pt.observations)
            shared.update((a, b) for i, a in enumerate(observers) for b in observers[i + 1 :])
        actual = {(a, b): w for a in self.covisibility.keyframes() for b, w in self.covisibility.weights(a).items() if a < b}
        if actual != dict(shared):
            diff = set(actual.items()) ^ set(shared.items())
            problems.append(f"covisibility weights differ from the recomputed ones at {sorted(diff)[:5]}")
        problems.extend(self._check_graph_nodes())
        return problems

    def _check_graph_nodes(self) -> list[str]:
        problems = []
        ids = sorted(self.keyframes)
        if self.covisibility.keyframes() != ids or self.spanning_tree.keyframes() != ids:
            problems.append("the graphs' keyframes differ from the map's")
            return problems
        for kf_id in ids:
            node, steps = kf_id, 0
            while (parent := self.spanning_tree.parent(node)) is not None and steps <= len(ids):
                if node not in self.spanning_tree.children(parent):
                    problems.append(f"keyframe {node} is not among the children of its parent {parent}")
                node, steps = parent, steps + 1
            if node != self.first_keyframe_id:
                problems.append(f"keyframe {kf_id} does not reach the first keyframe in the spanning tree")
        return problems
