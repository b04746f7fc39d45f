"""The frontend's cache of the map: keyframes, points as arrays, covisibility and the local window.

Points are stored as a struct of arrays indexed by *row* (an internal, dense index); their ids
are what leaves the frontend. Per-frame queries (local keyframes, local points) are vectorised
over these arrays; the per-keyframe bookkeeping (observations, covisibility) runs once per
keyframe.

Id spaces: point and keyframe ids come from ``IdAllocator(start, step)`` objects built from
``LocalMapConfig`` (``point_id_start``/``point_id_step``, ``keyframe_id_start``/
``keyframe_id_step``). The frontend's defaults start at 0 with step 1; a backend creating points
gives itself a disjoint space (for example a start with the high bit set) through its own
configuration, so no id needs a round trip.

The backend's corrections arrive as ``MapUpdate`` messages (replacement semantics, see
``zenslam.schemas.map_update``) and are applied with ``apply_map_update``.

The map is a bounded cache: ``retain`` evicts keyframes and their points (``cache_eviction``
decides which and when) and compacts slots and rows, so whoever holds slots or rows remaps them.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from zenslam.errors import ConfigError
from zenslam.frontend.id_index import IdIndex
from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.slot_graph import SlotGraph
from zenslam.geometry import invert_T, transform_points
from zenslam.map_point_rules import representative_descriptors, scale_invariance_range
from zenslam.map_rules_config import MapRulesConfig
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.schemas.relocalisation import MapPoints

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class LocalMapConfig:
    """Id spaces, local-window sizes and the recent-point culling rules of the frontend's map."""

    point_id_start: int = 0  # first id given to a point created by the frontend
    point_id_step: int = 1  # increment between consecutive point ids
    keyframe_id_start: int = 0  # first keyframe id
    keyframe_id_step: int = 1  # increment between consecutive keyframe ids
    max_local_keyframes: int = 80  # stop adding covisible neighbours past this many local keyframes
    best_covisible: int = 10  # neighbours examined per local keyframe (ORB-SLAM: 10)
    map_rules: MapRulesConfig = dataclasses.field(default_factory=MapRulesConfig)  # copy of the run's ``map`` section
    cull_recent_points: bool = True  # apply ORB-SLAM's recent map point culling at each keyframe
    cull_min_found_ratio: float = 0.25  # found / visible below this -> point removed
    cull_min_keyframe_observations: int = 2  # keyframes that must see a point 2 keyframes after its birth
    cull_window_keyframes: int = 3  # points stay "recent" (checked) for this many keyframes
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


class IdAllocator:
    """Hands out int ids start, start + step, start + 2 step, ... in order."""

    def __init__(self, start: int, step: int = 1) -> None:
        if step <= 0:
            raise ValueError(f"id step must be positive, got {step}")
        self._next = int(start)
        self._step = int(step)

    def next(self) -> int:
        """One new id."""
        value = self._next
        self._next += self._step
        return value

    def take(self, n: int) -> np.ndarray:
        """``n`` new ids as an (n,) int64 array."""
        ids = self._next + self._step * np.arange(n, dtype=np.int64)
        self._next += self._step * n
        return ids


@dataclass(frozen=True)
class LocalWindow:
    """The keyframes around the current frame (slots into the map) and the reference among them."""

    keyframe_slots: np.ndarray  # (L,) int64, the ones voted for first (most shared points first)
    reference_slot: int  # the keyframe sharing most points with the frame, -1 if none


_POINT_ARRAYS = {
    "ids": ((), np.int64),
    "p_world": ((3,), np.float64),
    "descriptors": ((32,), np.uint8),
    "normals": ((3,), np.float64),
    "min_distance_m": ((), np.float64),
    "max_distance_m": ((), np.float64),
    "n_visible": ((), np.int64),
    "n_found": ((), np.int64),
    "n_observations": ((), np.int64),
    "valid": ((), np.bool_),
    "created_serial": ((), np.int64),
    "covariance": ((3, 3), np.float64),
}
_OBS_ARRAYS = {"row": ((), np.int64), "slot": ((), np.int64), "keypoint": ((), np.int64), "desc": ((32,), np.uint8)}


def _grow(arrays: dict[str, np.ndarray], spec: dict, needed: int) -> None:
    capacity = next(iter(arrays.values())).shape[0]
    if needed <= capacity:
        return
    new_capacity = max(needed, 2 * capacity, 1024)
    for name, (shape, dtype) in spec.items():
        bigger = np.zeros((new_capacity, *shape), dtype=dtype)
        bigger[:capacity] = arrays[name]
        arrays[name] = bigger


def _compacted(arrays: dict[str, np.ndarray], spec: dict, index: np.ndarray) -> dict[str, np.ndarray]:
    """The rows ``index`` of ``arrays``, moved to the front of new arrays with room to grow by half."""
    capacity = max(len(index) + len(index) // 2, 1024)
    out = {}
    for name, (shape, dtype) in spec.items():
        out[name] = np.zeros((capacity, *shape), dtype=dtype)
        out[name][: len(index)] = arrays[name][index]
    return out


class LocalMap:
    """Keyframes, map points and covisibility as the frontend needs them for tracking.

    Keyframes are addressed by *slot* (insertion order), points by *row*; ``keyframe(slot).id``
    and ``point_ids[row]`` give the ids other stages use.
    """

    def __init__(self, config: LocalMapConfig | None = None) -> None:
        self.config = config or LocalMapConfig()
        self.point_id_allocator = IdAllocator(self.config.point_id_start, self.config.point_id_step)
        self.keyframe_id_allocator = IdAllocator(self.config.keyframe_id_start, self.config.keyframe_id_step)
        self._pts = {name: np.zeros((0, *shape), dtype=dtype) for name, (shape, dtype) in _POINT_ARRAYS.items()}
        self._obs = {name: np.zeros((0, *shape), dtype=dtype) for name, (shape, dtype) in _OBS_ARRAYS.items()}
        self._n_points = 0
        self._n_obs = 0
        self._id_index = IdIndex()
        self._keyframes: list[KeyFrame | None] = []  # None once removed by the backend
        self._slot_of_id: dict[int, int] = {}
        self._kf_rows: list[np.ndarray] = []  # per slot: rows of the points the keyframe observes
        self._kf_centres = np.zeros((0, 3))
        self._graph = SlotGraph(self.config.map_rules.min_covisibility_weight)
        self._n_inserted = 0  # keyframes ever inserted: the serial of the next one

    # ---- sizes and accessors -------------------------------------------------------------------
    @property
    def n_keyframes(self) -> int:
        """Keyframes inserted so far (removed and evicted ones included)."""
        return self._n_inserted

    @property
    def n_slots(self) -> int:
        """Keyframe slots in use (cached keyframes and the backend's removed ones until an eviction)."""
        return len(self._keyframes)

    @property
    def n_cached_keyframes(self) -> int:
        """Keyframes held: neither removed by the backend nor evicted."""
        return len(self._slot_of_id)

    @property
    def n_points(self) -> int:
        """Rows in use (culled points keep their row, with ``valid`` False)."""
        return self._n_points

    @property
    def n_valid_points(self) -> int:
        """Points not culled."""
        return int(np.count_nonzero(self.valid))

    def _view(self, name: str) -> np.ndarray:
        return self._pts[name][: self._n_points]

    point_ids = property(lambda self: self._view("ids"), doc="(M,) int64 id of each row")
    p_world = property(lambda self: self._view("p_world"), doc="(M, 3) positions, metres, world frame")
    descriptors = property(lambda self: self._view("descriptors"), doc="(M, 32) representative descriptors")
    normals = property(lambda self: self._view("normals"), doc="(M, 3) mean viewing directions, world frame")
    min_distance_m = property(lambda self: self._view("min_distance_m"), doc="(M,) scale-invariance minimum")
    max_distance_m = property(lambda self: self._view("max_distance_m"), doc="(M,) scale-invariance maximum")
    n_visible = property(lambda self: self._view("n_visible"), doc="(M,) frames whose frustum held the point")
    n_found = property(lambda self: self._view("n_found"), doc="(M,) frames where the point was an inlier")
    n_observations = property(lambda self: self._view("n_observations"), doc="(M,) keyframes observing it")
    valid = property(lambda self: self._view("valid"), doc="(M,) False once culled or removed")
    covariance = property(
        lambda self: self._view("covariance"), doc="(M, 3, 3) position covariance, m^2; zeros where not estimated (``set_covariances``)"
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
        return self._id_index.rows(point_ids)

    def observations(self, row: int) -> dict[int, int]:
        """Keyframe id -> keypoint index of every observation of the point in ``row``."""
        mask = self._obs["row"][: self._n_obs] == row
        slots = self._obs["slot"][: self._n_obs][mask]
        kps = self._obs["keypoint"][: self._n_obs][mask]
        return {self._keyframes[int(s)].id: int(k) for s, k in zip(slots, kps)}

    def observation_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every observation the cache holds as (row, slot, keypoint) arrays (n_obs,) int64, read-only views."""
        views = tuple(self._obs[name][: self._n_obs] for name in ("row", "slot", "keypoint"))
        for view in views:
            view.flags.writeable = False
        return views

    def set_covariances(self, rows: np.ndarray, covariance: np.ndarray) -> None:
        """Set the position covariance (K, 3, 3) of the points in ``rows`` (K,)."""
        self._pts["covariance"][np.asarray(rows, dtype=np.int64)] = covariance

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
        slot = len(self._keyframes)
        serial = self._n_inserted
        self._n_inserted += 1
        self._keyframes.append(keyframe)
        self._slot_of_id[int(keyframe.id)] = slot
        self._kf_centres = np.vstack([self._kf_centres, keyframe.centre_world[None]])
        new_rows = self._append_new_points(keyframe, serial)
        if point_rows is None:
            rows = self.rows_of_ids(keyframe.map_point_ids)
        else:
            rows = np.asarray(point_rows, dtype=np.int64).copy()
            rows[np.asarray(keyframe.new_point_keypoints, dtype=np.int64)] = new_rows
        observed = self._observe(slot, keyframe, rows)
        self._pts["n_observations"][observed] += 1
        self._refresh_points(observed)
        self._graph.add(self._links(slot, observed))
        return new_rows

    def _observe(self, slot: int, keyframe: KeyFrame, rows: np.ndarray) -> np.ndarray:
        """Record the observations of the new keyframe in ``slot`` matched to point ``rows`` (N,)
        (-1 none; culled points are skipped, one observation per point); returns the rows observed."""
        rows = rows.copy()
        rows[rows >= 0] = np.where(self.valid[rows[rows >= 0]], rows[rows >= 0], -1)
        keypoints, observed = _one_observation_per_point(rows)
        self._append_observations(slot, observed, keypoints, keyframe.descriptors[keypoints])
        self._kf_rows.append(observed)
        return observed

    def restore_keyframes(self, keyframes: Sequence[KeyFrame], points: MapPoints) -> list[int]:
        """Bring keyframes of the backend's map into the cache (evicted ones, or never held) with the
        points they observe, as the backend describes them (``points``); returns their new slots.

        Keyframes the cache holds stay as they are. Listed points the cache holds take the
        backend's values; unknown ones observed by a restored keyframe are created (as a map
        update creates them). A restored keyframe is no new keyframe: it does not advance
        ``n_keyframes`` (the clock of the recent-point culling), and it adds to ``n_observations``
        only of the points it brings (the others already count it, see ``retain``).
        """
        restored = [kf for kf in sorted(keyframes, key=lambda k: k.id) if self.slot_of(kf.id) < 0]
        observed = [np.asarray(kf.map_point_ids, dtype=np.int64) for kf in restored]
        known = self.rows_of_ids(points.ids) >= 0
        listed = MapUpdate(
            keyframe_id=-1, stamp_ns=0, point_ids=np.asarray(points.ids, dtype=np.int64), p_world=points.p_world,
            descriptors=points.descriptors, normals=points.normals, min_distance_m=points.min_distance_m,
            max_distance_m=points.max_distance_m,
        )  # fmt: skip
        self._replace_points(listed, np.concatenate(observed) if observed else np.zeros(0, dtype=np.int64))
        brought = np.zeros(self._n_points, dtype=bool)
        rows = self.rows_of_ids(points.ids)
        brought[rows[(rows >= 0) & ~known]] = True
        slots = []
        for keyframe in restored:
            slot = len(self._keyframes)
            self._keyframes.append(keyframe)
            self._slot_of_id[int(keyframe.id)] = slot
            self._kf_centres = np.vstack([self._kf_centres, keyframe.centre_world[None]])
            kf_rows = self._observe(slot, keyframe, self.rows_of_ids(keyframe.map_point_ids))
            self._pts["n_observations"][kf_rows[brought[kf_rows]]] += 1
            self._graph.add(self._links(slot, kf_rows))
            slots.append(slot)
        return slots

    def _append_new_points(self, keyframe: KeyFrame, serial: int) -> np.ndarray:
        n_new = len(keyframe.new_point_ids)
        start = self._n_points
        _grow(self._pts, _POINT_ARRAYS, start + n_new)
        rows = np.arange(start, start + n_new, dtype=np.int64)
        kps = np.asarray(keyframe.new_point_keypoints, dtype=np.int64)
        p = np.asarray(keyframe.new_points_world, dtype=float).reshape(n_new, 3)
        rays = p - keyframe.centre_world
        dist = np.linalg.norm(rays, axis=1)
        lo, hi = scale_invariance_range(dist, keyframe.level[kps], keyframe.scale_factor, keyframe.n_levels)
        pts = self._pts
        pts["ids"][rows] = keyframe.new_point_ids
        pts["p_world"][rows] = p
        pts["descriptors"][rows] = keyframe.descriptors[kps]
        pts["normals"][rows] = rays / np.maximum(dist, 1e-12)[:, None]
        pts["min_distance_m"][rows] = lo
        pts["max_distance_m"][rows] = hi
        pts["n_visible"][rows] = 1
        pts["n_found"][rows] = 1
        pts["n_observations"][rows] = 0
        pts["valid"][rows] = True
        pts["created_serial"][rows] = serial
        self._n_points = start + n_new
        self._id_index.add(keyframe.new_point_ids, rows)
        return rows

    def _append_observations(self, slot: int, rows: np.ndarray, keypoints: np.ndarray, desc: np.ndarray) -> None:
        start, n = self._n_obs, len(rows)
        _grow(self._obs, _OBS_ARRAYS, start + n)
        self._obs["row"][start : start + n] = rows
        self._obs["slot"][start : start + n] = slot
        self._obs["keypoint"][start : start + n] = keypoints
        self._obs["desc"][start : start + n] = desc
        self._n_obs = start + n

    def _refresh_points(self, rows: np.ndarray) -> None:
        """Recompute viewing directions and representative descriptors of ``rows`` from all their observations."""
        if len(rows) == 0:
            return
        mask = np.zeros(self._n_points, dtype=bool)
        mask[rows] = True
        obs_rows = self._obs["row"][: self._n_obs]
        entries = np.flatnonzero(mask[obs_rows])
        entries = entries[np.argsort(obs_rows[entries], kind="stable")]
        e_rows = obs_rows[entries]
        rays = self._pts["p_world"][e_rows] - self._kf_centres[self._obs["slot"][entries]]
        rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
        counts = np.bincount(e_rows, minlength=self._n_points)
        sums = np.stack([np.bincount(e_rows, weights=rays[:, k], minlength=self._n_points) for k in range(3)], 1)
        self._pts["normals"][rows] = sums[rows] / counts[rows, None]
        starts = np.cumsum(counts) - counts  # first sorted entry of each row (rows outside have none)
        desc = self._obs["desc"][entries]
        for k in np.unique(counts[rows]):
            group = rows[counts[rows] == k]
            index = starts[group][:, None] + np.arange(k)[None, :]
            self._pts["descriptors"][group] = representative_descriptors(desc[index])

    def _links(self, slot: int, rows: np.ndarray) -> dict[int, int]:
        """Covisibility links (other slot -> shared points) of ``slot`` observing the points ``rows``."""
        in_kf = np.zeros(self._n_points, dtype=bool)
        in_kf[rows] = True
        obs_rows = self._obs["row"][: self._n_obs]
        weights = np.bincount(self._obs["slot"][: self._n_obs][in_kf[obs_rows]], minlength=self.n_slots)
        weights[slot] = 0
        return {int(s): int(weights[s]) for s in np.flatnonzero(weights)}

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

    def local_window(self, frame_point_rows: np.ndarray) -> LocalWindow:
        """ORB-SLAM's ``UpdateLocalKeyFrames`` for a frame matched to ``frame_point_rows`` (-1 none).

        Every keyframe observing a matched point is local; then, while there are at most
        ``max_local_keyframes``, each of those adds its first not-yet-local keyframe among its
        10 best covisible ones, one child and its parent. The voted keyframes are visited by
        decreasing vote (ORB-SLAM's order is by pointer, i.e. arbitrary) and ORB-SLAM2's early
        exit after adding a parent is not reproduced.
        """
        rows = np.asarray(frame_point_rows, dtype=np.int64)
        rows = rows[rows >= 0]
        rows = rows[self.valid[rows]]
        if len(rows) == 0 or not self._keyframes:
            return LocalWindow(np.zeros(0, dtype=np.int64), -1)
        in_frame = np.zeros(self._n_points, dtype=bool)
        in_frame[rows] = True
        obs_rows = self._obs["row"][: self._n_obs]
        votes = np.bincount(self._obs["slot"][: self._n_obs][in_frame[obs_rows]], minlength=self.n_slots)
        voted = np.flatnonzero(votes)
        if len(voted) == 0:
            return LocalWindow(np.zeros(0, dtype=np.int64), -1)
        voted = voted[np.lexsort((voted, -votes[voted]))]
        selected = [int(s) for s in voted]
        included = set(selected)
        for slot in voted.tolist():
            if len(selected) > self.config.max_local_keyframes:
                break
            candidates = (
                self.best_covisible(slot, self.config.best_covisible),
                self._graph.children(slot),
                [self.parent(slot)] if self.parent(slot) >= 0 else [],
            )
            for group in candidates:
                for other in group:
                    if other not in included:
                        selected.append(other)
                        included.add(other)
                        break
        return LocalWindow(np.asarray(selected, dtype=np.int64), int(voted[0]))

    def local_point_rows(self, keyframe_slots: np.ndarray) -> np.ndarray:
        """ORB-SLAM's ``UpdateLocalPoints``: sorted unique rows of valid points seen by the keyframes."""
        if len(keyframe_slots) == 0:
            return np.zeros(0, dtype=np.int64)
        seen = np.zeros(self._n_points, dtype=bool)
        for slot in keyframe_slots:
            seen[self._kf_rows[int(slot)]] = True
        return np.flatnonzero(seen & self.valid)

    def tracked_points(self, slot: int, min_observations: int) -> int:
        """Valid points of the keyframe seen by at least ``min_observations`` keyframes."""
        rows = self.keyframe_point_rows(slot)
        return int(np.count_nonzero(self.n_observations[rows] >= min_observations))

    # ---- statistics and culling ------------------------------------------------------------------
    def increase_visible(self, rows: np.ndarray) -> None:
        """Count one more frame whose frustum held each point in ``rows`` (unique rows)."""
        self._pts["n_visible"][rows] += 1

    def increase_found(self, rows: np.ndarray) -> None:
        """Count one more frame where each point in ``rows`` (unique rows) was an inlier."""
        self._pts["n_found"][rows] += 1

    def cull_recent_points(self) -> int:
        """ORB-SLAM's ``MapPointCulling`` on points born in the last ``cull_window_keyframes`` keyframes.

        A recent point goes when its found ratio is below ``cull_min_found_ratio``, or when two or
        more keyframes have passed since its birth and fewer than ``cull_min_keyframe_observations``
        keyframes observe it. Returns the number culled.
        """
        cfg = self.config
        if not cfg.cull_recent_points or self.n_keyframes == 0:
            return 0
        age = (self.n_keyframes - 1) - self._view("created_serial")
        recent = self.valid & (age <= cfg.cull_window_keyframes)
        ratio = self.n_found / np.maximum(self.n_visible, 1)
        bad = recent & (
            (ratio < cfg.cull_min_found_ratio)
            | ((age >= 2) & (self.n_observations < cfg.cull_min_keyframe_observations))
        )
        self._pts["valid"][np.flatnonzero(bad)] = False
        return int(np.count_nonzero(bad))

    # ---- eviction ---------------------------------------------------------------------------------
    def cached_slots(self) -> np.ndarray:
        """(K,) int64 slots of the keyframes held, ascending (insertion order)."""
        return np.asarray(sorted(self._slot_of_id.values()), dtype=np.int64)

    def nbytes(self) -> int:
        """Bytes of the arrays the cache holds: point and observation arrays (their capacity), the
        keyframes' arrays (keypoints, descriptors, depths, associations, new points) and the indexes."""
        arrays = [*self._pts.values(), *self._obs.values(), self._kf_centres, *self._kf_rows]
        for keyframe in self._keyframes:
            if keyframe is not None:
                arrays += [getattr(keyframe.features, f.name) for f in dataclasses.fields(keyframe.features)]
                arrays += [keyframe.T_world_cam, keyframe.right_u, keyframe.depth_m, keyframe.map_point_ids]
                arrays += [keyframe.new_point_ids, keyframe.new_point_keypoints, keyframe.new_points_world]
        return int(sum(np.asarray(a).nbytes for a in arrays)) + self._id_index.nbytes

    def retain(self, keep_slots: np.ndarray, keep_rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Evict every keyframe not in ``keep_slots`` and every point that no kept keyframe observes
        (except ``keep_rows``, rows the caller still refers to), then compact slots and rows.

        Kept keyframes and points keep their relative order, so every ranking tie-breaks as
        before. Points keep their statistics, ``n_observations`` included (it counts the backend
        map's keyframes, which evicted ones still are). A kept keyframe whose spanning-tree parent
        goes hangs from its nearest kept ancestor. Returns ``(slot_map, row_map)``: the new slot
        (resp. row) of each old one, -1 where evicted; callers holding slots or rows remap them.
        """
        n_obs = self._n_obs
        kept_slot = np.zeros(self.n_slots, dtype=bool)
        kept_slot[np.asarray(keep_slots, dtype=np.int64)] = True
        kept_slot &= np.asarray([kf is not None for kf in self._keyframes], dtype=bool)
        kept_obs = kept_slot[self._obs["slot"][:n_obs]]
        kept_row = np.zeros(self._n_points, dtype=bool)
        kept_row[self._obs["row"][:n_obs][kept_obs]] = True
        if keep_rows is not None:
            extra = np.asarray(keep_rows, dtype=np.int64)
            kept_row[extra[extra >= 0]] = True
        slot_map = np.where(kept_slot, np.cumsum(kept_slot) - 1, -1)
        row_map = np.where(kept_row, np.cumsum(kept_row) - 1, -1)
        rows = np.flatnonzero(kept_row)
        self._pts = _compacted(self._pts, _POINT_ARRAYS, rows)
        self._n_points = len(rows)
        self._id_index = IdIndex()
        self._id_index.add(self._pts["ids"][: self._n_points], np.arange(self._n_points, dtype=np.int64))
        self._obs = _compacted(self._obs, _OBS_ARRAYS, np.flatnonzero(kept_obs))
        self._n_obs = int(np.count_nonzero(kept_obs))
        self._obs["row"][: self._n_obs] = row_map[self._obs["row"][: self._n_obs]]
        self._obs["slot"][: self._n_obs] = slot_map[self._obs["slot"][: self._n_obs]]
        slots = np.flatnonzero(kept_slot).tolist()
        self._keyframes = [self._keyframes[s] for s in slots]
        self._slot_of_id = {int(kf.id): new for new, kf in enumerate(self._keyframes)}
        self._kf_rows = [row_map[self._kf_rows[s]] for s in slots]
        self._kf_centres = self._kf_centres[slots]
        self._graph.compact(slot_map.tolist())
        return slot_map, row_map

    # ---- map updates from elsewhere --------------------------------------------------------------
    def set_point_positions(self, point_ids: np.ndarray, p_world: np.ndarray) -> int:
        """Move known points (ids) to new world positions (K, 3) metres; unknown ids are ignored.

        The hook through which the backend's refined positions reach the frontend. Returns how
        many points were updated.
        """
        rows = self.rows_of_ids(point_ids)
        known = rows >= 0
        self._pts["p_world"][rows[known]] = np.asarray(p_world, dtype=float).reshape(-1, 3)[known]
        return int(np.count_nonzero(known))

    def remove_points(self, point_ids: np.ndarray) -> int:
        """Mark known points (ids) as removed; returns how many were known."""
        rows = self.rows_of_ids(point_ids)
        rows = rows[rows >= 0]
        self._pts["valid"][rows] = False
        return len(rows)

    def apply_map_update(self, update: MapUpdate) -> None:
        """Apply the backend's correction: replace listed points (creating unknown ones), keyframe
        poses and keypoint-to-point associations, then delete removed points and keyframes.

        Replacement semantics make a second application harmless. Keyframes this map does not
        hold (never had, or evicted) are skipped: it cannot rebuild their keypoints. Unknown points
        are created only when a held keyframe listed in the update observes them: the cache holds
        its keyframes' points (tracking reaches points through keyframes), so an evicted point
        comes back when a held keyframe is associated with it again, and a correction listing the
        whole map does not copy it into the cache. Points listed by the backend are never culled
        by ``cull_recent_points``: the backend decides about them.
        """
        corrections = self._fitting(update.keyframes)
        moved = self._poses_of(corrections)
        held = [c.map_point_ids for c in corrections if self.slot_of(c.id) >= 0]
        self._replace_points(update, np.concatenate(held) if held else np.zeros(0, dtype=np.int64))
        self._replace_keyframes(corrections)
        self._carry_unmapped_keyframes(update, moved)
        self.remove_points(update.removed_point_ids)
        for keyframe_id in np.asarray(update.removed_keyframe_ids, dtype=np.int64).tolist():
            self._remove_keyframe(keyframe_id)

    def _fitting(self, corrections: Sequence[KeyframeCorrection]) -> list[KeyframeCorrection]:
        """``corrections`` less those of held keyframes whose associations do not list one point
        per keypoint: a damaged message, which names a keyframe it cannot describe (skipped, with a
        warning; the keyframe keeps what it had)."""
        fitting = []
        for correction in corrections:
            slot = self.slot_of(correction.id)
            keyframe = self._keyframes[slot] if slot >= 0 else None
            if keyframe is not None and len(correction.map_point_ids) != len(keyframe.map_point_ids):
                logger.warning(
                    "map update: keyframe %d's correction lists %d point associations for its %d keypoints; skipped",
                    correction.id, len(correction.map_point_ids), len(keyframe.map_point_ids),
                )  # fmt: skip
                continue
            fitting.append(correction)
        return fitting

    def _poses_of(self, corrections: list[KeyframeCorrection]) -> dict[int, np.ndarray]:
        """Slot -> current T_world_cam of the known keyframes among ``corrections``."""
        slots = (self.slot_of(c.id) for c in corrections)
        return {s: self._keyframes[s].T_world_cam for s in slots if s >= 0 and self._keyframes[s] is not None}

    def _carry_unmapped_keyframes(self, update: MapUpdate, before: dict[int, np.ndarray]) -> None:
        """Move the keyframes made after ``update.keyframe_id`` (the backend has not mapped them
        yet) and the points they created with their spanning-tree parent's correction, as ORB-SLAM
        corrects the last frame through its reference keyframe: without it, tracking between an
        update and the next would mix the corrected map with keyframes placed on the old one."""
        correction = {s: self._keyframes[s].T_world_cam @ invert_T(T) for s, T in before.items()}
        for slot, keyframe in enumerate(self._keyframes):
            if keyframe is None or keyframe.id <= update.keyframe_id or slot in before or self.parent(slot) not in correction:
                continue
            C = correction[slot] = correction[self.parent(slot)]
            self._keyframes[slot] = dataclasses.replace(keyframe, T_world_cam=C @ keyframe.T_world_cam)
            self._kf_centres[slot] = self._keyframes[slot].centre_world
            rows = self.rows_of_ids(keyframe.new_point_ids[~np.isin(keyframe.new_point_ids, update.point_ids)])
            rows = rows[rows >= 0]
            self._pts["p_world"][rows] = transform_points(C, self._pts["p_world"][rows])

    def _replace_points(self, update: MapUpdate, observed_ids: np.ndarray) -> None:
        """Replace the listed points this map holds and create the unknown ones among ``observed_ids``."""
        rows = self.rows_of_ids(update.point_ids)
        unknown = np.flatnonzero(rows < 0)
        unknown = unknown[np.isin(update.point_ids[unknown], observed_ids)]
        if len(unknown):
            start = self._n_points
            _grow(self._pts, _POINT_ARRAYS, start + len(unknown))
            rows[unknown] = np.arange(start, start + len(unknown))
            self._n_points = start + len(unknown)
            new = rows[unknown]
            self._pts["ids"][new] = update.point_ids[unknown]
            self._pts["n_visible"][new] = 1
            self._pts["n_found"][new] = 1
            self._pts["n_observations"][new] = 0
            self._id_index.add(update.point_ids[unknown], new)
        listed = np.flatnonzero(rows >= 0)
        rows = rows[listed]
        pts = self._pts
        pts["p_world"][rows] = update.p_world[listed]
        pts["descriptors"][rows] = update.descriptors[listed]
        pts["normals"][rows] = update.normals[listed]
        pts["min_distance_m"][rows] = update.min_distance_m[listed]
        pts["max_distance_m"][rows] = update.max_distance_m[listed]
        pts["valid"][rows] = True
        pts["created_serial"][rows] = np.iinfo(np.int64).min // 2  # never "recent" again

    def _replace_keyframes(self, corrections: list[KeyframeCorrection]) -> None:
        """Replace the poses and associations of the known keyframes among ``corrections``: their
        old observations go in one pass over the observation arrays, then each gets its new ones."""
        replaced = []
        for correction in corrections:
            slot = self.slot_of(correction.id)
            if slot >= 0 and self._keyframes[slot] is not None:
                self._keyframes[slot] = dataclasses.replace(
                    self._keyframes[slot],
                    T_world_cam=np.asarray(correction.T_world_cam, dtype=float),
                    map_point_ids=np.asarray(correction.map_point_ids, dtype=np.int64),
                )
                self._kf_centres[slot] = self._keyframes[slot].centre_world
                replaced.append(slot)
        self._drop_observations(replaced)
        if not replaced:
            return
        associations = [self._keyframes[slot].map_point_ids for slot in replaced]
        all_rows = self.rows_of_ids(np.concatenate(associations))  # one lookup for every keyframe
        known = np.flatnonzero(all_rows >= 0)
        all_rows[known[~self.valid[all_rows[known]]]] = -1
        for slot, rows in zip(replaced, np.split(all_rows, np.cumsum([len(ids) for ids in associations])[:-1])):
            keypoints, observed = _one_observation_per_point(rows)
            self._append_observations(slot, observed, keypoints, self._keyframes[slot].descriptors[keypoints])
            self._pts["n_observations"][observed] += 1
            self._kf_rows[slot] = observed
        for slot in replaced:
            self._graph.set_links(slot, self._links(slot, self._kf_rows[slot]))

    def _drop_observations(self, slots: list[int]) -> None:
        """Delete every observation made by the keyframes in ``slots`` (compacting the arrays once)."""
        if not slots:
            return
        n = self._n_obs
        doomed = np.zeros(self.n_slots, dtype=bool)
        doomed[slots] = True
        mine = doomed[self._obs["slot"][:n]]
        np.subtract.at(self._pts["n_observations"], self._obs["row"][:n][mine], 1)
        keep = np.flatnonzero(~mine)
        for name in _OBS_ARRAYS:
            self._obs[name][: len(keep)] = self._obs[name][keep]
        self._n_obs = len(keep)
        for slot in slots:
            self._kf_rows[slot] = np.zeros(0, dtype=np.int64)

    def _remove_keyframe(self, keyframe_id: int) -> None:
        """Forget a keyframe: its observations and links go, its children move to its parent."""
        slot = self.slot_of(keyframe_id)
        if slot < 0 or self._keyframes[slot] is None:
            return
        self._drop_observations([slot])
        self._graph.remove(slot)
        self._keyframes[slot] = None
        del self._slot_of_id[int(keyframe_id)]


def _one_observation_per_point(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The keypoints (ascending) and point rows a keyframe observes, from each keypoint's point row
    ``rows`` (-1 none): a point associated with two keypoints is observed at the first."""
    keypoints = np.flatnonzero(rows >= 0)
    observed = rows[keypoints]
    if len(observed) > 1 and not np.all(np.diff(np.sort(observed))):  # not all distinct (rare): unique pass
        _, first = np.unique(observed, return_index=True)
        keypoints = keypoints[np.sort(first)]
        observed = rows[keypoints]
    return keypoints, observed
