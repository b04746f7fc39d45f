"""Recomputing map points' derived attributes (ORB-SLAM's ComputeDistinctiveDescriptors and UpdateNormalAndDepth).

The points' observations are flattened into arrays once per refresh, each point's sorted by
keyframe id; the representative descriptors and the mean viewing directions come from one
compiled pass over each point's run of observations.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import chain
from operator import attrgetter

import numpy as np

from zenslam.backend.keyframe import BackendKeyframe
from zenslam.backend.map_point import MapPoint
from zenslam.backend.point_store import PointStore
from zenslam.map_point_rules import mean_viewing_directions_of_runs, representative_offsets, scale_invariance_range

_OBSERVATIONS, _ROW, _FIRST_KEYFRAME = attrgetter("observations"), attrgetter("row"), attrgetter("first_keyframe_id")


@dataclass(frozen=True)
class ObservationTable:
    """The observations of P points as flat arrays, each point's contiguous and by increasing keyframe id."""

    counts: np.ndarray  # (P,) observations per point
    starts: np.ndarray  # (P,) index of each point's first observation
    keyframe_ids: np.ndarray  # (O,) observing keyframe
    keyframe_rows: np.ndarray  # (O,) its row in the map's keyframe insertion order
    keypoints: np.ndarray  # (O,) keypoint index in that keyframe

    @classmethod
    def of(cls, points: list[MapPoint], keyframe_order: np.ndarray) -> ObservationTable:
        """Observations of ``points``; ``keyframe_order`` (K,) int64 lists the map's keyframe ids in insertion order."""
        # map() over C-level callables: no Python frame per point or observation (thousands a keyframe).
        observations = list(map(_OBSERVATIONS, points))
        counts = np.fromiter(map(len, observations), dtype=np.int64, count=len(observations))
        total = int(counts.sum())
        kf_ids = np.fromiter(chain.from_iterable(observations), dtype=np.int64, count=total)
        keypoints = np.fromiter(chain.from_iterable(map(dict.values, observations)), dtype=np.int64, count=total)
        starts = np.cumsum(counts) - counts
        # Observations are mostly made in keyframe order: sort only when some point's are not.
        step_down = np.flatnonzero(np.diff(kf_ids) <= 0) + 1  # where the id does not increase
        if np.any(np.isin(step_down, starts, invert=True)):  # ... other than at a point's first observation
            # By (point, keyframe id) as one int64 key: a stable sort of nearly sorted keys is
            # cheaper than a lexsort of the two, for the same order (the pairs are distinct).
            owner = np.repeat(np.arange(len(points), dtype=np.int64), counts)
            span = int(kf_ids.max()) - int(kf_ids.min()) + 1
            if len(points) * span < 2**62:
                order = np.argsort(owner * span + (kf_ids - kf_ids.min()), kind="stable")
            else:
                order = np.lexsort((kf_ids, owner))
            kf_ids, keypoints = kf_ids[order], keypoints[order]
        sorter = np.argsort(keyframe_order, kind="stable")
        rows = sorter[np.searchsorted(keyframe_order, kf_ids, sorter=sorter)]
        return cls(counts, starts, kf_ids, rows, keypoints)


def _descriptors_at(keyframes: list[BackendKeyframe], rows: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Descriptors (M, 32) uint8 of (keyframe row in insertion order, keypoint) pairs, in order."""
    out = np.empty((len(rows), 32), dtype=np.uint8)
    order = np.argsort(rows, kind="stable")
    bounds = [0, *(np.flatnonzero(np.diff(rows[order])) + 1).tolist(), len(order)] if len(order) else [0]
    for a, b in zip(bounds[:-1], bounds[1:]):  # slices of one keyframe's pairs (cheaper than np.split)
        sel = order[a:b]
        out[sel] = np.take(keyframes[int(rows[sel[0]])].descriptors, keypoints[sel], axis=0)
    return out


def refresh_descriptors(
    keyframes: list[BackendKeyframe], store: PointStore, rows: np.ndarray, table: ObservationTable, selected: np.ndarray
) -> None:
    """Give each ``selected`` point (bool (P,) over the table's points, which are at ``rows`` in
    ``store``) the representative descriptor of its observations."""
    chosen = np.flatnonzero(selected & (table.counts > 0))
    if len(chosen) == 0:
        return
    counts = table.counts[chosen]
    run_starts = np.cumsum(counts) - counts  # each point's run in the gathered descriptors
    at = np.arange(int(counts.sum())) + np.repeat(table.starts[chosen] - run_starts, counts)
    descriptors = _descriptors_at(keyframes, table.keyframe_rows[at], table.keypoints[at])
    store.descriptor[rows[chosen]] = descriptors[run_starts + representative_offsets(descriptors, run_starts, counts)]


def refresh_geometry(
    keyframes: list[BackendKeyframe],
    store: PointStore,
    rows: np.ndarray,
    first_keyframe_ids: np.ndarray,
    table: ObservationTable,
    selected: np.ndarray,
) -> None:
    """Give each ``selected`` point (bool (P,) over the table's points) its mean viewing direction
    and scale-invariance distance range (from its distance to its reference keyframe and the
    keypoint's level there)."""
    chosen = np.flatnonzero(selected)
    if len(chosen) == 0:
        return
    centres = np.array([kf.T_world_cam[:3, 3] for kf in keyframes], dtype=float)
    p_world = np.take(store.p_world, rows, axis=0)
    ref = _reference_observations(table, chosen, first_keyframe_ids[chosen])
    distance = np.linalg.norm(p_world[chosen] - centres[table.keyframe_rows[ref]], axis=1)
    ref_rows, ref_keypoints = table.keyframe_rows[ref], table.keypoints[ref]
    # The reference keyframes' levels stacked, one gather for all points rather than one per keyframe.
    used, which = np.unique(ref_rows, return_inverse=True)
    refs = [keyframes[r] for r in used.tolist()]
    starts = np.cumsum([0, *(kf.n_keypoints for kf in refs)])[:-1]
    level = np.concatenate([kf.levels for kf in refs])[starts[which] + ref_keypoints]
    pyramids = [(kf.scale_factor, kf.n_levels) for kf in refs]
    for scale_factor, n_levels in sorted(set(pyramids)):
        if len(set(pyramids)) == 1:
            sel = np.arange(len(chosen))
        else:
            sel = np.flatnonzero(np.array([p == (scale_factor, n_levels) for p in pyramids])[which])
        lo, hi = scale_invariance_range(distance[sel], level[sel], scale_factor, n_levels)
        store.min_distance_m[rows[chosen[sel]]] = lo
        store.max_distance_m[rows[chosen[sel]]] = hi
    store.normal[rows[chosen]] = mean_viewing_directions_of_runs(
        p_world[chosen], centres[table.keyframe_rows], table.starts[chosen], table.counts[chosen]
    )


def _reference_observations(table: ObservationTable, chosen: np.ndarray, first_keyframe_ids: np.ndarray) -> np.ndarray:
    """Index (into the table) of each chosen point's reference observation: by the keyframe that
    created it (``first_keyframe_ids``, one per chosen point) while it still observes it, else by
    the observer with the smallest id."""
    starts, counts = table.starts[chosen], table.counts[chosen]
    owner = np.repeat(np.arange(len(chosen)), counts)
    at = np.arange(len(owner)) + np.repeat(starts - (np.cumsum(counts) - counts), counts)
    hit = table.keyframe_ids[at] == first_keyframe_ids[owner]
    ref = starts.copy()
    ref[owner[hit]] = at[hit]
    return ref


def refresh_points(
    keyframes: dict[int, BackendKeyframe],
    points: dict[int, MapPoint],
    store: PointStore,
    descriptor_ids: list[int],
    geometry_ids: list[int],
) -> None:
    """Recompute the representative descriptors of ``descriptor_ids`` and the viewing directions and
    distance ranges of ``geometry_ids`` (sorted ids of observed points, whose rows are in ``store``)."""
    if descriptor_ids is geometry_ids or not (descriptor_ids and geometry_ids):
        ids = descriptor_ids or geometry_ids
    else:
        ids = sorted(set(descriptor_ids) | set(geometry_ids))
    if not ids:
        return
    pts = list(map(points.__getitem__, ids))
    kf_list = list(keyframes.values())
    table = ObservationTable.of(pts, np.fromiter(keyframes, dtype=np.int64, count=len(keyframes)))
    rows = np.fromiter(map(_ROW, pts), dtype=np.int64, count=len(pts))
    first = np.fromiter(map(_FIRST_KEYFRAME, pts), dtype=np.int64, count=len(pts))
    ids_arr = np.asarray(ids, dtype=np.int64)
    by_descriptor = _members(ids_arr, descriptor_ids)
    by_geometry = by_descriptor if geometry_ids is descriptor_ids else _members(ids_arr, geometry_ids)
    refresh_descriptors(kf_list, store, rows, table, by_descriptor)
    refresh_geometry(kf_list, store, rows, first, table, by_geometry)


def _members(ids: np.ndarray, subset: list[int]) -> np.ndarray:
    """(len(ids),) bool: ``ids`` (sorted) that are in ``subset`` (sorted, a subset of ``ids``)."""
    if len(subset) == len(ids):
        return np.ones(len(ids), dtype=bool)
    mask = np.zeros(len(ids), dtype=bool)
    mask[np.searchsorted(ids, np.asarray(subset, dtype=np.int64))] = True
    return mask
