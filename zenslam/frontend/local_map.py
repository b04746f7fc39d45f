"""The frontend's cache of the map: keyframes, points as arrays, observations and covisibility.

Points are stored as a struct of arrays indexed by *row* (an internal, dense index, see
``map_arrays``); their ids are what leaves the frontend. Per-frame queries (``local_window``) are
vectorised over these arrays; the per-keyframe bookkeeping (observations, covisibility) runs
once per keyframe.

Id spaces: point and keyframe ids come from ``IdAllocator(start, step)`` objects built from
``LocalMapConfig`` (``point_id_start``/``point_id_step``, ``keyframe_id_start``/
``keyframe_id_step``). The frontend's defaults start at 0 with step 1; a backend creating points
gives itself a disjoint space (for example a start with the high bit set) through its own
configuration, so no id needs a round trip.

The backend's corrections arrive as ``MapUpdate`` messages and are applied by ``map_sync``
through the replacement primitives at the end of ``LocalMap``.

The map is a bounded cache: ``retain`` evicts keyframes and their points (``cache_eviction``
decides which and when) and compacts slots and rows, so whoever holds slots or rows remaps them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from zenslam.errors import ConfigError
from zenslam.frontend.id_allocator import IdAllocator
from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.map_arrays import one_observation_per_point
from zenslam.frontend.observation_table import ObservationTable, refresh_points
from zenslam.frontend.point_table import PointTable
from zenslam.frontend.slot_graph import SlotGraph
from zenslam.map_point_rules import scale_invariance_range
from zenslam.map_rules_config import MapRulesConfig
from zenslam.schemas.map_update import MapUpdate



@dataclass(frozen=True)
class LocalMapConfig:
    """Id spaces, local-window sizes and cache bounds of the frontend's map (the backend culls points)."""

    point_id_start: int = 0  # first id given to a point created by the frontend
    point_id_step: int = 1  # increment between consecutive point ids
    keyframe_id_start: int = 0  # first keyframe id
    keyframe_id_step: int = 1  # increment between consecutive keyframe ids
    max_local_keyframes: int = 80  # stop adding covisible neighbours past this many local keyframes
    best_covisible: int = 10  # neighbours examined per local keyframe (ORB-SLAM: 10)
    map_rules: MapRulesConfig = dataclasses.field(default_factory=MapRulesConfig)  # copy of the run's ``map`` section
    # The map is a bounded cache of the backend's (see cache_eviction): past cache_max_keyframes,
    # keyframes outside the tracking window and its margin are evicted with the points they alone see.
    evict: bool = True  # False: nothing is evicted and the cache grows into a full copy of the map
    cache_max_keyframes: int = 120  # keyframes held before an eviction pass runs
    cache_margin_keyframes: int = 20  # keyframes kept beyond the tracking window (best covisible first)
    cache_min_keyframes_between_evictions: int = 20  # keyframes inserted between two passes, at least

    def __post_init__(self) -> None:
        lowest = {"cache_max_keyframes": 1, "cache_margin_keyframes": 0, "cache_min_keyframes_between_evictions": 1}
        problems = [f"{k}={getattr(self, k)} must be at least {low}" for k, low in lowest.items() if getattr(self, k) < low]
        if problems:
            raise ConfigError("invalid frontend local_map configuration: " + "; ".join(problems))


class LocalMap:
    """Keyframes, map points and covisibility as the frontend needs them for tracking.

    Keyframes are addressed by *slot* (insertion order), points by *row*; ``keyframe(slot).id``
    and ``point_ids[row]`` give the ids other stages use.
    """

    def __init__(self, config: LocalMapConfig | None = None) -> None:
        self.config = config or LocalMapConfig()
        self.point_id_allocator = IdAllocator(self.config.point_id_start, self.config.point_id_step)
        self.keyframe_id_allocator = IdAllocator(self.config.keyframe_id_start, self.config.keyframe_id_step)
        self._points = PointTable()
        self._obs = ObservationTable()
        self._keyframes: list[KeyFrame | None] = []  # None once removed by the backend
        self._slot_of_id: dict[int, int] = {}
        self._kf_rows: list[np.ndarray] = []  # per slot: rows of the points the keyframe observes
        self._kf_centres = np.zeros((0, 3))
        self._graph = SlotGraph(self.config.map_rules.min_covisibility_weight)
        self._n_inserted = 0  # keyframes ever inserted

    # ---- sizes and accessors -------------------------------------------------------------------
    n_keyframes = property(lambda self: self._n_inserted, doc="keyframes inserted so far (removed and evicted ones included)")
    n_slots = property(
        lambda self: len(self._keyframes), doc="keyframe slots in use (cached keyframes and the backend's removed ones until an eviction)"
    )
    n_cached_keyframes = property(lambda self: len(self._slot_of_id), doc="keyframes held: neither removed by the backend nor evicted")
    n_points = property(lambda self: self._points.n, doc="rows in use (removed points keep their row, with ``valid`` False)")
    n_valid_points = property(lambda self: int(np.count_nonzero(self.valid)), doc="points not removed")
    point_ids = property(lambda self: self._points.view("ids"), doc="(M,) int64 id of each row")
    p_world = property(lambda self: self._points.view("p_world"), doc="(M, 3) positions, metres, world frame")
    descriptors = property(lambda self: self._points.view("descriptors"), doc="(M, 32) representative descriptors")
    normals = property(lambda self: self._points.view("normals"), doc="(M, 3) mean viewing directions, world frame")
    min_distance_m = property(lambda self: self._points.view("min_distance_m"), doc="(M,) scale-invariance minimum")
    max_distance_m = property(lambda self: self._points.view("max_distance_m"), doc="(M,) scale-invariance maximum")
    n_visible = property(lambda self: self._points.view("n_visible"), doc="(M,) frames whose frustum held the point")
    n_found = property(lambda self: self._points.view("n_found"), doc="(M,) frames where the point was an inlier")
    n_observations = property(lambda self: self._points.view("n_observations"), doc="(M,) keyframes observing it")
    valid = property(lambda self: self._points.view("valid"), doc="(M,) False once removed by the backend")
    covariance = property(
        lambda self: self._points.view("covariance"), doc="(M, 3, 3) position covariance, m^2; zeros where not estimated (``set_covariances``)"
    )

    def keyframe(self, slot: int) -> KeyFrame | None:
        """The keyframe in ``slot``, None if the backend removed it."""
        return self._keyframes[slot]

    def slot_of(self, keyframe_id: int) -> int:
        """Slot of a keyframe id, -1 when unknown."""
        return self._slot_of_id.get(int(keyframe_id), -1)

    def keyframe_point_rows(self, slot: int) -> np.ndarray:
        """Rows of the valid points observed by the keyframe in ``slot``."""
        rows = self._kf_rows[slot]
        return rows[self.valid[rows]]

    def rows_of_ids(self, point_ids: np.ndarray) -> np.ndarray:
        """Rows (int64) of point ids; -1 for negative or unknown ids."""
        return self._points.rows_of_ids(point_ids)

    def observations(self, row: int) -> dict[int, int]:
        """Keyframe id -> keypoint index of every observation of the point in ``row``."""
        mask = self._obs.view("row") == row
        slots = self._obs.view("slot")[mask]
        kps = self._obs.view("keypoint")[mask]
        return {self._keyframes[int(s)].id: int(k) for s, k in zip(slots, kps)}

    def observation_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every observation the cache holds as (row, slot, keypoint) arrays (n_obs,) int64, read-only views."""
        views = tuple(self._obs.view(name) for name in ("row", "slot", "keypoint"))
        for view in views:
            view.flags.writeable = False
        return views

    def set_covariances(self, rows: np.ndarray, covariance: np.ndarray) -> None:
        """Set the position covariance (K, 3, 3) of the points in ``rows`` (K,)."""
        self._points.arrays["covariance"][np.asarray(rows, dtype=np.int64)] = covariance

    # ---- ids -------------------------------------------------------------------------------------
    def new_keyframe_id(self) -> int:
        """A fresh keyframe id from this map's id space."""
        return self.keyframe_id_allocator.next()

    def new_point_ids(self, n: int) -> np.ndarray:
        """``n`` fresh point ids (n,) int64 from this map's id space."""
        return self.point_id_allocator.take(n)

    # ---- insertion -------------------------------------------------------------------------------
    def insert_keyframe(self, keyframe: KeyFrame, point_rows: np.ndarray | None = None) -> np.ndarray:
        """Add a keyframe, create its new points, record its observations, update covisibility.

        ``keyframe.map_point_ids`` must name points already in the map or among
        ``keyframe.new_point_ids``. ``point_rows`` (N,), when the caller knows them, are the rows of
        the already-known points per keypoint (-1 elsewhere, including at the new points), which
        saves looking the ids up. Returns the rows (P,) of the new points. Observations refresh
        the observed points' representative descriptors and viewing directions.
        """
        self._n_inserted += 1
        slot = self._new_slot(keyframe)
        new_rows = self._append_new_points(keyframe)
        if point_rows is None:
            rows = self.rows_of_ids(keyframe.map_point_ids)
        else:
            rows = np.asarray(point_rows, dtype=np.int64).copy()
            rows[np.asarray(keyframe.new_point_keypoints, dtype=np.int64)] = new_rows
        observed = self._observe(slot, keyframe, rows)
        self._points.arrays["n_observations"][observed] += 1
        refresh_points(self._points, self._obs, self._kf_centres, observed)
        self._graph.add(self._obs.links(slot, observed, self._points.n, self.n_slots))
        return new_rows

    def add_held_keyframe(self, keyframe: KeyFrame, counted: np.ndarray) -> int:
        """Hold a keyframe of the backend's map (restored, see ``map_sync.restore_keyframes``)
        observing its associated points; it adds to ``n_observations`` of the rows where
        ``counted`` (a mask over rows) is set. Not a new keyframe: ``n_keyframes`` stays. Returns its slot."""
        slot = self._new_slot(keyframe)
        kf_rows = self._observe(slot, keyframe, self.rows_of_ids(keyframe.map_point_ids))
        self._points.arrays["n_observations"][kf_rows[counted[kf_rows]]] += 1
        self._graph.add(self._obs.links(slot, kf_rows, self._points.n, self.n_slots))
        return slot

    def _new_slot(self, keyframe: KeyFrame) -> int:
        slot = len(self._keyframes)
        self._keyframes.append(keyframe)
        self._slot_of_id[int(keyframe.id)] = slot
        self._kf_centres = np.vstack([self._kf_centres, keyframe.centre_world[None]])
        return slot

    def _observe(self, slot: int, keyframe: KeyFrame, rows: np.ndarray) -> np.ndarray:
        """Record the observations of the new keyframe in ``slot`` matched to point ``rows`` (N,)
        (-1 none; removed points are skipped, one observation per point); returns the rows observed."""
        rows = rows.copy()
        rows[rows >= 0] = np.where(self.valid[rows[rows >= 0]], rows[rows >= 0], -1)
        keypoints, observed = one_observation_per_point(rows)
        self._obs.append(slot, observed, keypoints, keyframe.descriptors[keypoints])
        self._kf_rows.append(observed)
        return observed

    def _append_new_points(self, keyframe: KeyFrame) -> np.ndarray:
        """The keyframe's new points, seen from it: viewing direction and distance range from its centre."""
        kps = np.asarray(keyframe.new_point_keypoints, dtype=np.int64)
        p = np.asarray(keyframe.new_points_world, dtype=float).reshape(len(keyframe.new_point_ids), 3)
        rays = p - keyframe.centre_world
        dist = np.linalg.norm(rays, axis=1)
        lo, hi = scale_invariance_range(dist, keyframe.level[kps], keyframe.scale_factor, keyframe.n_levels)
        normals = rays / np.maximum(dist, 1e-12)[:, None]
        return self._points.append(keyframe.new_point_ids, p, keyframe.descriptors[kps], normals, lo, hi)

    # ---- covisibility queries --------------------------------------------------------------------
    def covisibility_weight(self, slot_a: int, slot_b: int) -> int:
        """Points observed by both keyframes."""
        return self._graph.weight(slot_a, slot_b)

    def best_covisible(self, slot: int, n: int) -> list[int]:
        """Up to ``n`` connected keyframes (slots), strongest first."""
        return self._graph.ordered(slot)[:n]

    def parent(self, slot: int) -> int:
        """Spanning-tree parent (the best covisible keyframe at insertion), -1 for the first."""
        return self._graph.parent(slot)

    def children(self, slot: int) -> list[int]:
        """Spanning-tree children, in insertion order."""
        return list(self._graph.children(slot))

    def tracked_points(self, slot: int, min_observations: int) -> int:
        """Valid points of the keyframe seen by at least ``min_observations`` keyframes."""
        rows = self.keyframe_point_rows(slot)
        return int(np.count_nonzero(self.n_observations[rows] >= min_observations))

    # ---- statistics --------------------------------------------------------------------------------
    def increase_visible(self, rows: np.ndarray) -> None:
        """Count one more frame whose frustum held each point in ``rows`` (unique rows)."""
        self._points.arrays["n_visible"][rows] += 1

    def increase_found(self, rows: np.ndarray) -> None:
        """Count one more frame where each point in ``rows`` (unique rows) was an inlier."""
        self._points.arrays["n_found"][rows] += 1

    # ---- eviction ---------------------------------------------------------------------------------
    def cached_slots(self) -> np.ndarray:
        """(K,) int64 slots of the keyframes held, ascending (insertion order)."""
        return np.asarray(sorted(self._slot_of_id.values()), dtype=np.int64)

    def nbytes(self) -> int:
        """Bytes of the arrays the cache holds: point and observation arrays (their capacity), the
        keyframes' arrays (keypoints, descriptors, depths, associations, new points) and the indexes."""
        arrays = [self._kf_centres, *self._kf_rows]
        for keyframe in self._keyframes:
            if keyframe is not None:
                arrays += [getattr(keyframe.features, f.name) for f in dataclasses.fields(keyframe.features)]
                arrays += [keyframe.T_world_cam, keyframe.right_u, keyframe.depth_m, keyframe.map_point_ids]
                arrays += [keyframe.new_point_ids, keyframe.new_point_keypoints, keyframe.new_points_world]
        return int(sum(np.asarray(a).nbytes for a in arrays)) + self._points.nbytes + self._obs.nbytes

    def retain(self, keep_slots: np.ndarray, keep_rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Evict every keyframe not in ``keep_slots`` and every point that no kept keyframe observes
        (except ``keep_rows``, rows the caller still refers to), then compact slots and rows.

        Kept keyframes and points keep their relative order, so every ranking tie-breaks as
        before. Points keep their statistics, ``n_observations`` included (it counts the backend
        map's keyframes, which evicted ones still are). A kept keyframe whose spanning-tree parent
        goes hangs from its nearest kept ancestor. Returns ``(slot_map, row_map)``: the new slot
        (resp. row) of each old one, -1 where evicted; callers holding slots or rows remap them.
        """
        kept_slot = np.zeros(self.n_slots, dtype=bool)
        kept_slot[np.asarray(keep_slots, dtype=np.int64)] = True
        kept_slot &= np.asarray([kf is not None for kf in self._keyframes], dtype=bool)
        kept_obs = kept_slot[self._obs.view("slot")]
        kept_row = np.zeros(self._points.n, dtype=bool)
        kept_row[self._obs.view("row")[kept_obs]] = True
        if keep_rows is not None:
            extra = np.asarray(keep_rows, dtype=np.int64)
            kept_row[extra[extra >= 0]] = True
        slot_map = np.where(kept_slot, np.cumsum(kept_slot) - 1, -1)
        row_map = np.where(kept_row, np.cumsum(kept_row) - 1, -1)
        self._points.keep(np.flatnonzero(kept_row))
        self._obs.keep(kept_obs, row_map, slot_map)
        slots = np.flatnonzero(kept_slot).tolist()
        self._keyframes = [self._keyframes[s] for s in slots]
        self._slot_of_id = {int(kf.id): new for new, kf in enumerate(self._keyframes)}
        self._kf_rows = [row_map[self._kf_rows[s]] for s in slots]
        self._kf_centres = self._kf_centres[slots]
        self._graph.compact(slot_map.tolist())
        return slot_map, row_map

    # ---- map updates (applied by map_sync) --------------------------------------------------------------
    def set_point_positions(self, point_ids: np.ndarray, p_world: np.ndarray) -> int:
        """Move known points (ids) to new world positions (K, 3) metres; unknown ids are ignored.

        The hook through which the backend's refined positions reach the frontend. Returns how
        many points were updated.
        """
        rows = self.rows_of_ids(point_ids)
        known = rows >= 0
        self._points.arrays["p_world"][rows[known]] = np.asarray(p_world, dtype=float).reshape(-1, 3)[known]
        return int(np.count_nonzero(known))

    def remove_points(self, point_ids: np.ndarray) -> int:
        """Mark known points (ids) as removed; returns how many were known."""
        rows = self.rows_of_ids(point_ids)
        rows = rows[rows >= 0]
        self._points.arrays["valid"][rows] = False
        return len(rows)

    def replace_points(self, update: MapUpdate, observed_ids: np.ndarray) -> None:
        """Replace the points ``update`` lists that this map holds (position, descriptor, viewing
        direction, distance range; valid again) and create the unknown ones among ``observed_ids``."""
        self._points.replace(update, observed_ids)

    def replace_keyframe(self, slot: int, keyframe: KeyFrame) -> None:
        """Put ``keyframe`` (the same id, a new pose or associations) in ``slot``; its observations
        follow its associations only after ``reobserve``."""
        self._keyframes[slot] = keyframe
        self._kf_centres[slot] = keyframe.centre_world

    def set_row_positions(self, rows: np.ndarray, p_world: np.ndarray) -> None:
        """Move the points in ``rows`` (K,) to world positions ``p_world`` (K, 3) metres."""
        self._points.arrays["p_world"][rows] = p_world

    def reobserve(self, slots: list[int]) -> None:
        """Observations and covisibility of the keyframes in ``slots`` from their associations: their
        old observations go in one pass over the observation arrays, then each gets its new ones."""
        self._drop_observations(slots)
        if not slots:
            return
        associations = [self._keyframes[slot].map_point_ids for slot in slots]
        all_rows = self.rows_of_ids(np.concatenate(associations))  # one lookup for every keyframe
        known = np.flatnonzero(all_rows >= 0)
        all_rows[known[~self.valid[all_rows[known]]]] = -1
        for slot, rows in zip(slots, np.split(all_rows, np.cumsum([len(ids) for ids in associations])[:-1])):
            keypoints, observed = one_observation_per_point(rows)
            self._obs.append(slot, observed, keypoints, self._keyframes[slot].descriptors[keypoints])
            self._points.arrays["n_observations"][observed] += 1
            self._kf_rows[slot] = observed
        for slot in slots:
            self._graph.set_links(slot, self._obs.links(slot, self._kf_rows[slot], self._points.n, self.n_slots))

    def _drop_observations(self, slots: list[int]) -> None:
        """Delete every observation made by the keyframes in ``slots`` (compacting the arrays once)."""
        if not slots:
            return
        doomed = np.zeros(self.n_slots, dtype=bool)
        doomed[slots] = True
        np.subtract.at(self._points.arrays["n_observations"], self._obs.drop(doomed), 1)
        for slot in slots:
            self._kf_rows[slot] = np.zeros(0, dtype=np.int64)

    def remove_keyframe(self, keyframe_id: int) -> None:
        """Forget a keyframe (the backend removed it): its observations and links go, its children
        move to its parent; unknown ids are ignored."""
        slot = self.slot_of(keyframe_id)
        if slot < 0 or self._keyframes[slot] is None:
            return
        self._drop_observations([slot])
        self._graph.remove(slot)
        self._keyframes[slot] = None
        del self._slot_of_id[int(keyframe_id)]
