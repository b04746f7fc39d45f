"""The backend's map: keyframes and map points with their observations, kept consistent with the graphs.

Every change goes through ``BackendMap`` methods, which keep the two sides of each observation
(``MapPoint.observations[kf_id] = keypoint`` and ``BackendKeyframe.map_point_ids[keypoint] =
point id``, with the point's store row in ``map_point_rows``), the covisibility weights, the
spanning tree and the essential graph's loop edges in step, and record what changed
(``MapChanges``) so the local mapper can publish a map update.

Keyframes and points are objects in dicts (ids, observations, counts); the points' positions,
descriptors, viewing directions and distance ranges are columns of a ``PointStore``, so the
per-keyframe work over thousands of points reads and writes them as arrays (``point_geometry``,
``positions``, the rows a keyframe keeps of its points) rather than one object at a time.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from itertools import chain, compress
from operator import attrgetter

import numpy as np

from zenslam.backend.covisibility import CovisibilityGraph
from zenslam.backend.culled_keyframes import CulledKeyframes
from zenslam.backend.essential_graph import EssentialGraph
from zenslam.backend.keyframe import BackendKeyframe
from zenslam.backend.map_consistency import consistency_problems
from zenslam.backend.map_point import FrustumProjection, MapPoint, PointGeometry, frustum_projection
from zenslam.backend.point_refresh import refresh_points
from zenslam.backend.point_store import COLUMNS, PointStore
from zenslam.backend.spanning_tree import SpanningTree, choose_parent
from zenslam.errors import ZenslamError
from zenslam.schemas.map_update import BACKEND_POINT_ID_BASE

logger = logging.getLogger(__name__)
_ID, _ROW, _OBSERVATIONS = attrgetter("id"), attrgetter("row"), attrgetter("observations")

__all__ = [
    "BackendKeyframe", "BackendMap", "FrustumProjection", "IdAllocator", "MapChanges", "MapCheckpoint", "MapError", "MapPoint",
    "PointGeometry", "frustum_projection",
]  # fmt: skip


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


@dataclass
class MapChanges:
    """What changed in the map since the last ``BackendMap.take_changes``."""

    keyframes: set[int] = field(default_factory=set)  # pose or associations changed
    points: set[int] = field(default_factory=set)  # created, moved, or descriptor/normal/range refreshed
    created_points: set[int] = field(default_factory=set)  # created here with an allocated id
    removed_points: set[int] = field(default_factory=set)
    removed_keyframes: set[int] = field(default_factory=set)

    def copy(self) -> MapChanges:
        """A log with copies of these sets."""
        return MapChanges(
            set(self.keyframes), set(self.points), set(self.created_points), set(self.removed_points), set(self.removed_keyframes)
        )


@dataclass(frozen=True)
class MapCheckpoint:
    """The part of the map a tentative change may touch, as it was (``BackendMap.checkpoint``)."""

    points: dict[int, MapPoint]  # the map's points then (membership and order)
    point_state: tuple[tuple[MapPoint, dict[int, int], int, int, int], ...]  # point, observations, visible, found, weighted
    store: PointStore
    store_rows: int  # rows handed out then
    rows: np.ndarray  # (R,) store rows copied: the scope's points and those waiting for a refresh
    columns: dict[str, np.ndarray]  # the store's columns (``point_store.COLUMNS``) at those rows
    keyframes: tuple[tuple[BackendKeyframe, np.ndarray, np.ndarray, np.ndarray], ...]  # keyframe, pose, point ids, rows
    covisibility: dict[int, dict[int, int]]  # the scope keyframes' weights
    replaced: dict[int, int]
    stale: tuple[frozenset[int], frozenset[int]]  # descriptor, geometry
    changes: MapChanges  # a copy of the change log
    changes_log: MapChanges  # the log itself: ``take_changes`` since would lose what to put back


class BackendMap:
    """Keyframes, map points and their graphs, changed only through these methods."""

    def __init__(
        self, min_covisibility_weight: int = 15, essential_min_weight: int = 100, point_id_start: int = BACKEND_POINT_ID_BASE
    ) -> None:
        self.keyframes: dict[int, BackendKeyframe] = {}  # in insertion order
        self.points: dict[int, MapPoint] = {}
        self.point_store = PointStore()  # the points' positions, descriptors, normals and ranges (rows)
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

    def next_ids(self) -> dict[str, int]:
        """First ids a frontend or a run continuing this map may use, past every id the map knows
        (fused ids and culled keyframes too): ``keyframe``, ``frontend_point``, ``backend_point``."""
        fused = self._replaced
        point_ids = np.array([*self.points, *fused, *fused.values()], dtype=np.int64)
        frontend = point_ids[point_ids < BACKEND_POINT_ID_BASE]
        backend = point_ids[point_ids >= BACKEND_POINT_ID_BASE]
        keyframes = [*self.keyframes, *(k for k, _ in self.culled.entries())]
        return {
            "keyframe": 1 + max(keyframes, default=-1),
            "frontend_point": int(frontend.max()) + 1 if len(frontend) else 0,
            "backend_point": max(self.point_id_allocator.upcoming, int(backend.max()) + 1 if len(backend) else 0),
        }

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

    def keyframe_points(self, kf_id: int) -> tuple[np.ndarray, np.ndarray]:
        """Ids and ``point_store`` rows (each (M,) int64) of the points ``kf_id`` observes, in keypoint order."""
        kf = self.keyframe(kf_id)
        associated = kf.map_point_ids >= 0
        return kf.map_point_ids[associated], kf.map_point_rows[associated]

    def point_rows(self, point_ids) -> np.ndarray:
        """Rows (int64) in ``point_store`` of ``point_ids`` (ints or an int array); MapError when one is unknown."""
        ids = point_ids.tolist() if isinstance(point_ids, np.ndarray) else point_ids
        try:  # map() over C-level callables: no Python frame per point (thousands a keyframe)
            return np.fromiter(map(_ROW, map(self.points.__getitem__, ids)), dtype=np.int64, count=len(ids))
        except KeyError as missing:
            raise MapError(f"map point {missing.args[0]} is not in the backend map") from None

    def positions(self, point_ids) -> np.ndarray:
        """(M, 3) positions of ``point_ids`` (metres, world frame; a copy)."""
        return np.take(self.point_store.p_world, self.point_rows(point_ids), axis=0)

    def point_descriptors(self, point_ids) -> np.ndarray:
        """(M, 32) uint8 representative descriptors of ``point_ids`` (a copy, as last refreshed)."""
        return np.take(self.point_store.descriptor, self.point_rows(point_ids), axis=0)

    def point_geometry(self, point_ids) -> PointGeometry:
        """Positions, viewing directions and distance ranges of ``point_ids`` as arrays, in order
        (as last refreshed: call ``refresh_points`` first for current ones)."""
        return PointGeometry.at(self.point_store, self.point_rows(point_ids))

    # ---- points ------------------------------------------------------------------------------------
    def add_point(self, point_id: int, p_world: np.ndarray, first_keyframe_id: int) -> MapPoint:
        """A point without observations yet (add them with ``add_observation``)."""
        return self.add_points([point_id], np.asarray(p_world, dtype=float).reshape(1, 3), first_keyframe_id)[0]

    def add_points(self, point_ids: list[int], p_world: np.ndarray, first_keyframe_id: int) -> list[MapPoint]:
        """Points ``point_ids`` (distinct, unused) at the rows of ``p_world`` (M, 3), without
        observations yet: what ``add_point`` of each in turn makes, their rows taken a block at a time."""
        ids = [int(p) for p in point_ids]
        p_world = np.asarray(p_world, dtype=float).reshape(len(ids), 3)
        points, replaced = self.points, self._replaced
        used = [p for p in ids if p in points or p in replaced]
        if used:
            raise MapError(f"map point id {used[0]} is already used; ids are never reused")
        if len(set(ids)) != len(ids):
            raise MapError(f"map point id {next(p for p in ids if ids.count(p) > 1)} is given twice; ids are never reused")
        if ids and min(ids) < 0:
            raise MapError(f"map point ids are non-negative, got {min(ids)}")
        serial = self._next_serial - 1
        out: list[MapPoint] = []
        while len(out) < len(ids):
            if self.point_store.full and 2 * len(points) <= self.point_store.capacity:
                self._compact_point_store()
            store, done = self.point_store, len(out)
            first_row, n = store.append_rows(len(ids) - done)
            store.p_world[first_row : first_row + n] = p_world[done : done + n]
            for point_id, row in zip(ids[done : done + n], range(first_row, first_row + n)):
                pt = points[point_id] = MapPoint(point_id, store, row, first_keyframe_id, serial)
                out.append(pt)
        self.changes.points.update(ids)
        return out

    def add_observed_points(self, point_ids: list[int], p_world: np.ndarray, kf_id: int, keypoints: list[int]) -> None:
        """Points ``point_ids`` created at keyframe ``kf_id`` (metres, world frame, rows of ``p_world``
        (M, 3)), each observed by it at ``keypoints[m]``: ``add_point`` then ``add_observation`` for each."""
        kf = self.keyframe(kf_id)
        p_world = np.asarray(p_world, dtype=float).reshape(len(point_ids), 3)
        at = np.asarray(keypoints, dtype=np.int64)
        taken = at[kf.map_point_ids[at] >= 0]
        if len(taken) or len(np.unique(at)) != len(at):
            keypoint = int(taken[0]) if len(taken) else int(at[0])
            raise MapError(f"keypoint {keypoint} of keyframe {kf_id} already observes a point, or gets two new ones")
        self._observe_all(self.add_points(point_ids, p_world, kf_id), kf, at)

    def _compact_point_store(self) -> None:
        """Move the live points into a new store without the rows of removed ones."""
        points = list(self.points.values())
        old_rows = np.fromiter((pt.row for pt in points), dtype=np.int64, count=len(points))
        store = self.point_store.compacted(old_rows)
        for row, pt in enumerate(points):
            pt.move_to(store, row)
        new_row = np.full(self.point_store.n_rows, -1, dtype=np.int64)
        new_row[old_rows] = np.arange(len(points))
        for kf in self.keyframes.values():
            associated = kf.map_point_rows >= 0
            kf.map_point_rows[associated] = new_row[kf.map_point_rows[associated]]
        self.point_store = store

    def new_point(self, p_world: np.ndarray, first_keyframe_id: int) -> MapPoint:
        """A point created by the backend, with the next id of its own id space."""
        pt = self.add_point(self.point_id_allocator.next(), p_world, first_keyframe_id)
        self.changes.created_points.add(pt.id)
        return pt

    def new_points_between(
        self, p_world: np.ndarray, kf_id: int, keypoints: np.ndarray, other_id: int, other_keypoints: np.ndarray
    ) -> list[int]:
        """Points created by the backend at keyframe ``kf_id`` (``new_point`` of each row of ``p_world``
        (M, 3), metres, world frame), observed by it at ``keypoints`` (M,) and by ``other_id`` at
        ``other_keypoints`` (M,), as ``add_observation`` would record them; returns their ids."""
        kf, other = self.keyframe(kf_id), self.keyframe(other_id)
        keypoints, other_keypoints = np.asarray(keypoints, dtype=np.int64), np.asarray(other_keypoints, dtype=np.int64)
        if kf_id == other_id:
            raise MapError(f"new points between keyframe {kf_id} and itself")
        for k, at in ((kf, keypoints), (other, other_keypoints)):
            if np.any(k.map_point_ids[at] >= 0) or len(np.unique(at)) != len(at):
                raise MapError(f"keypoints of keyframe {k.id} already observe points or are listed twice")
        p_world = np.asarray(p_world, dtype=float).reshape(-1, 3)
        ids = [self.point_id_allocator.next() for _ in range(len(p_world))]
        points = self.add_points(ids, p_world, kf_id)
        self.changes.created_points.update(ids)
        self._observe_all(points, kf, keypoints)
        if points:
            self.covisibility.add_shared(other_id, {kf_id: len(points)})  # each new point: +1 for the pair
        self._observe_all(points, other, other_keypoints)
        return list(map(_ID, points))

    def add_observation(self, point_id: int, kf_id: int, keypoint: int) -> None:
        """Keypoint ``keypoint`` of keyframe ``kf_id`` observes point ``point_id``."""
        pt, kf = self.point(point_id), self.keyframe(kf_id)
        if kf_id in pt.observations:
            raise MapError(f"point {point_id} is already observed by keyframe {kf_id} (keypoint {pt.observations[kf_id]})")
        if kf.map_point_ids[keypoint] >= 0:
            raise MapError(f"keypoint {keypoint} of keyframe {kf_id} already observes point {kf.map_point_ids[keypoint]}")
        self.covisibility.add_observation(kf_id, pt.observations.keys())
        self._observe(pt, kf, int(keypoint))

    def _observe(self, pt: MapPoint, kf: BackendKeyframe, keypoint: int) -> None:
        """Record one observation on both sides (covisibility is the caller's)."""
        pt.observations[kf.id] = keypoint
        pt.weighted_observations += 2 if kf.right_u[keypoint] >= 0 else 1
        kf.map_point_ids[keypoint] = pt.id
        kf.map_point_rows[keypoint] = pt.row
        self._touch(pt.id, kf.id)

    def _observe_all(self, points: list[MapPoint], kf: BackendKeyframe, keypoints: np.ndarray) -> None:
        """``_observe`` of each of ``points`` (distinct, none observed by ``kf``) at ``keypoints`` (distinct,
        free): the keyframe's arrays and the change log written once for all."""
        kf_id = kf.id
        for pt, keypoint, stereo in zip(points, keypoints.tolist(), (kf.right_u[keypoints] >= 0).tolist()):
            pt.observations[kf_id] = keypoint
            pt.weighted_observations += 2 if stereo else 1
        ids = list(map(_ID, points))
        kf.map_point_ids[keypoints] = ids
        kf.map_point_rows[keypoints] = list(map(_ROW, points))
        self._stale_descriptor.update(ids)
        self._stale_geometry.update(ids)
        self.changes.points.update(ids)
        if ids:
            self.changes.keyframes.add(kf_id)

    def remove_observation(self, point_id: int, kf_id: int) -> None:
        """Keyframe ``kf_id`` no longer observes point ``point_id`` (the point stays)."""
        pt, kf = self.point(point_id), self.keyframe(kf_id)
        if kf_id not in pt.observations:
            raise MapError(f"point {point_id} is not observed by keyframe {kf_id}")
        self._unobserve(pt, kf)
        self.covisibility.remove_observation(kf_id, pt.observations.keys())

    def _unobserve(self, pt: MapPoint, kf: BackendKeyframe) -> None:
        """Drop one observation on both sides (covisibility is the caller's)."""
        keypoint = pt.observations.pop(kf.id)
        pt.weighted_observations -= 2 if kf.right_u[keypoint] >= 0 else 1
        kf.map_point_ids[keypoint] = -1
        kf.map_point_rows[keypoint] = -1
        self._touch(pt.id, kf.id)

    def _touch(self, point_id: int, kf_id: int) -> None:
        self._stale_descriptor.add(point_id)
        self._stale_geometry.add(point_id)
        self.changes.keyframes.add(kf_id)
        self.changes.points.add(point_id)

    def remove_point(self, point_id: int) -> None:
        """Delete a point and all its observations."""
        pt = self.point(point_id)
        observers = sorted(pt.observations)
        self.covisibility.remove_shared(observers)
        keyframes, changed = self.keyframes, self.changes.keyframes
        for kf_id in observers:  # ``_unobserve`` without marking the point, which goes
            kf = keyframes[kf_id]
            keypoint = pt.observations.pop(kf_id)
            pt.weighted_observations -= 2 if kf.right_u[keypoint] >= 0 else 1
            kf.map_point_ids[keypoint] = -1
            kf.map_point_rows[keypoint] = -1
            changed.add(kf_id)
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
        items = sorted(old.observations.items())
        # What ``remove_observation`` then ``add_observation`` per observer of old add up to: its
        # observers stop sharing old (-1 for each pair of them), and each not observing new yet
        # starts sharing new with new's observers.
        self.covisibility.remove_shared([kf_id for kf_id, _ in items])
        for kf_id, keypoint in items:
            kf = self.keyframes[kf_id]
            self._unobserve(old, kf)
            if kf_id not in new.observations:
                self.covisibility.add_observation(kf_id, new.observations.keys())
                self._observe(new, kf, keypoint)
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
        self.point(point_id).p_world = np.asarray(p_world, dtype=float).reshape(3)
        self._stale_geometry.add(point_id)
        self.changes.points.add(point_id)

    def set_point_positions(self, point_ids: list[int], p_world: np.ndarray) -> None:
        """Move points ``point_ids`` to the rows of ``p_world`` (N, 3) (metres, world frame)."""
        rows = self.point_rows(point_ids)
        self.point_store.p_world[rows] = np.asarray(p_world, dtype=float).reshape(len(rows), 3)
        self._stale_geometry.update(point_ids)
        self.changes.points.update(point_ids)

    # ---- keyframes ---------------------------------------------------------------------------------
    def add_keyframe(self, kf: BackendKeyframe) -> None:
        """Insert a keyframe: its ``map_point_ids`` (existing points, each at most once) become
        observations, covisibility is updated and its spanning-tree parent chosen among the others."""
        if kf.id in self.keyframes or kf.id in self.spanning_tree:
            raise MapError(f"keyframe {kf.id} is already in the backend map; keyframe ids must be unique")
        requested = np.asarray(kf.map_point_ids, dtype=np.int64).copy()
        keypoints = np.flatnonzero(requested >= 0)
        known = requested[keypoints]
        points = self.points
        missing = sorted({p for p in known.tolist() if p not in points})
        if missing or len(np.unique(known)) != len(known):
            raise MapError(
                f"keyframe {kf.id} associates unknown points {missing[:5]} or one point twice; resolve ids first"
            )
        older = list(self.keyframes)
        kf.map_point_ids = np.full(kf.n_keypoints, -1, dtype=np.int64)
        kf.map_point_rows = np.full(kf.n_keypoints, -1, dtype=np.int64)
        kf.serial = self._next_serial
        self._next_serial += 1
        self.keyframes[kf.id] = kf
        self.covisibility.add_keyframe(kf.id)
        observed = list(map(points.__getitem__, known.tolist()))
        # Each point is observed once, so the new keyframe shares with every other keyframe as many
        # points as it sees of that keyframe's (counted in first-seen order).
        self.covisibility.add_shared(kf.id, Counter(chain.from_iterable(map(_OBSERVATIONS, observed))))
        self._observe_all(observed, kf, keypoints)
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
            self._unobserve(self.points[point_id], kf)
        self.covisibility.remove_keyframe(kf_id)  # with all its weights: it no longer shares any point
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
        desc_ids = self._observed(self._stale_descriptor)
        same = self._stale_geometry == self._stale_descriptor  # mostly: observations change both
        geo_ids = desc_ids if same else self._observed(self._stale_geometry)
        refresh_points(self.keyframes, self.points, self.point_store, desc_ids, geo_ids)
        self.changes.points.update(desc_ids)
        if not same:
            self.changes.points.update(geo_ids)
        self._stale_descriptor.clear()
        self._stale_geometry.clear()
        return len(desc_ids) if same else len(set(desc_ids) | set(geo_ids))

    def _observed(self, point_ids: set[int]) -> list[int]:
        """The sorted ids among ``point_ids`` (live points) that some keyframe observes."""
        ordered = sorted(point_ids)
        # map() over C-level callables: no Python frame per point (thousands a keyframe)
        return list(compress(ordered, map(len, map(_OBSERVATIONS, map(self.points.__getitem__, ordered)))))

    # ---- checkpoints ---------------------------------------------------------------------------------
    def checkpoint(self, point_ids: Iterable[int], keyframe_ids: Iterable[int] = ()) -> MapCheckpoint:
        """What ``restore`` needs to undo a change confined to ``point_ids``, their observers and
        ``keyframe_ids``: observations added, moved or merged among them, their poses, positions and
        refreshed attributes. Points may be merged away in between, none added."""
        points = self.points
        scope = sorted({int(p) for p in point_ids if p in points})
        kf_ids = sorted({int(k) for k in keyframe_ids} | {k for p in scope for k in points[p].observations})
        waiting = self._stale_descriptor | self._stale_geometry
        rows = self.point_rows(sorted(set(scope) | waiting))
        store = self.point_store
        log = self.changes
        return MapCheckpoint(
            points=dict(points),
            point_state=tuple(
                (pt, dict(pt.observations), pt.n_visible, pt.n_found, pt.weighted_observations)
                for pt in (points[p] for p in scope)
            ),
            store=store,
            store_rows=store.n_rows,
            rows=rows,
            columns={name: np.take(getattr(store, name), rows, axis=0) for name in COLUMNS},
            keyframes=tuple(
                (kf, kf.T_world_cam.copy(), kf.map_point_ids.copy(), kf.map_point_rows.copy())
                for kf in (self.keyframe(k) for k in kf_ids)
            ),
            covisibility={k: self.covisibility.weights(k) for k in kf_ids},
            replaced=dict(self._replaced),
            stale=(frozenset(self._stale_descriptor), frozenset(self._stale_geometry)),
            changes=log.copy(),
            changes_log=log,
        )

    def restore(self, checkpoint: MapCheckpoint) -> None:
        """Put the map back as it was at ``checkpoint``; MapError when something outside its scope
        changed since, points were added, or the changes were taken in between (nothing restored)."""
        log, cp = self.changes, checkpoint
        if log is not cp.changes_log or self.point_store is not cp.store or cp.store.n_rows != cp.store_rows:
            raise MapError("the map cannot go back to this checkpoint: changes were taken or points added since")
        in_scope = {pt.id for pt, *_ in cp.point_state} | cp.stale[0] | cp.stale[1]
        points = (log.points | log.removed_points) - cp.changes.points - cp.changes.removed_points - in_scope
        keyframes = log.keyframes - cp.changes.keyframes - {kf.id for kf, *_ in cp.keyframes}
        if points or keyframes:
            raise MapError(
                f"points {sorted(points)[:10]} and keyframes {sorted(keyframes)[:10]} changed outside the checkpoint's "
                "scope: widen it to every point and keyframe the change touches"
            )
        self.points.clear()
        self.points.update(cp.points)
        for pt, observations, visible, found, weighted in cp.point_state:
            pt.observations, pt.n_visible, pt.n_found, pt.weighted_observations = dict(observations), visible, found, weighted
        for name, saved in cp.columns.items():
            getattr(cp.store, name)[cp.rows] = saved
        for kf, T_world_cam, point_ids, rows in cp.keyframes:
            kf.T_world_cam, kf.map_point_ids[:], kf.map_point_rows[:] = T_world_cam.copy(), point_ids, rows
        self.covisibility.restore_weights(cp.covisibility)
        self._replaced = dict(cp.replaced)
        self._stale_descriptor, self._stale_geometry = set(cp.stale[0]), set(cp.stale[1])
        self.changes = cp.changes.copy()

    # ---- change log and checks -----------------------------------------------------------------------
    def take_changes(self) -> MapChanges:
        """What changed since the last call (pending refreshes are applied first); resets the log."""
        self.refresh_points()
        changes, self.changes = self.changes, MapChanges()
        return changes

    def check_consistency(self) -> list[str]:
        """Every broken invariant, described (empty when the map is consistent)."""
        return consistency_problems(self)
