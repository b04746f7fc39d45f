"""Eviction from the frontend's map cache: keep the tracking window, a margin, and what updates need.

The backend owns the map; the frontend's ``LocalMap`` is a cache of its neighbourhood. Once the
cache holds more than ``LocalMapConfig.cache_max_keyframes`` keyframes (and at least
``cache_min_keyframes_between_evictions`` were inserted since the last pass, so a window larger
than the limit does not cost a pass per keyframe), one pass keeps:
- the tracking window: ORB-SLAM's local keyframes of the current frame (``local_window``:
  the keyframes sharing points with it, their best covisible neighbours, a child and the parent);
- a margin: ``cache_margin_keyframes`` more, taken ring by ring along the best covisible
  neighbours of the window, so the next frames' windows still find their neighbours cached;
- the reference keyframe, the keyframes the backend has not answered yet and their spanning-tree
  parents (a map update carries an unanswered keyframe with its parent's correction);
and evicts every other keyframe with the points that no kept keyframe observes.

Map updates that name evicted keyframes skip them (the frontend cannot rebuild their keypoints);
an evicted point listed by an update comes back only when a held keyframe of the update observes
it (``map_sync.apply_map_update``): the cache re-fills with what its keyframes see, and a correction
listing the whole map does not copy it in. Points that lose their last held observer go at the
next pass.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.local_window import local_window

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Eviction:
    """What one pass did: old slot -> new slot and old row -> new row (-1 evicted), and the counts."""

    slot_map: np.ndarray  # (old slots,) int64
    row_map: np.ndarray  # (old rows,) int64
    keyframes_kept: int
    keyframes_evicted: int
    points_kept: int
    points_evicted: int


def keyframes_to_keep(
    local_map: LocalMap, frame_rows: np.ndarray, protected_slots: list[int], margin_keyframes: int
) -> np.ndarray:
    """Sorted unique slots (int64) of the tracking window of a frame matched to ``frame_rows``
    (map rows per keypoint, -1 none), its margin and ``protected_slots`` (negative ones ignored)."""
    window = local_window(local_map, frame_rows).keyframe_slots.tolist()
    kept = set(window)
    ring = window
    added = 0
    while ring and added < margin_keyframes:
        next_ring = []
        for slot in ring:
            for other in local_map.best_covisible(slot, local_map.config.best_covisible):
                if other not in kept and added < margin_keyframes:
                    kept.add(other)
                    next_ring.append(other)
                    added += 1
        ring = next_ring
    kept.update(s for s in protected_slots if s >= 0)
    return np.asarray(sorted(kept), dtype=np.int64)


class CacheEviction:
    """Decides when the cache is evicted and runs the pass (see the module doc)."""

    def __init__(self, local_map: LocalMap) -> None:
        self.map = local_map
        self.config = local_map.config
        self._inserted_at_last_pass = 0
        self.passes = 0

    def due(self) -> bool:
        """Whether the cache is past its size and enough keyframes came since the last pass."""
        cfg = self.config
        return (
            cfg.evict
            and self.map.n_cached_keyframes > cfg.cache_max_keyframes
            and self.map.n_keyframes - self._inserted_at_last_pass >= cfg.cache_min_keyframes_between_evictions
        )

    def maybe_evict(
        self, frame_rows: np.ndarray, reference_slot: int, unanswered: int, keep_rows: np.ndarray | None = None,
        force: bool = False,
    ) -> Eviction | None:
        """Evict when ``due`` (or ``force``, with eviction on: a cache filled by restored keyframes,
        which no insertion paces): keep the window of a frame matched to ``frame_rows``, the margin,
        the ``reference_slot``, the newest ``unanswered`` keyframes (sent to the backend, whose
        update has not been applied) and their parents, and the points rows ``keep_rows``. None
        when not due."""
        if not (self.due() or (force and self.config.evict)):
            return None
        cached = self.map.cached_slots()
        newest = cached[len(cached) - min(unanswered, len(cached)) :].tolist()
        protected = [reference_slot, *newest, *(self.map.parent(s) for s in newest)]
        keep = keyframes_to_keep(self.map, frame_rows, protected, self.config.cache_margin_keyframes)
        n_points = self.map.n_points
        slot_map, row_map = self.map.retain(keep, keep_rows)
        self._inserted_at_last_pass = self.map.n_keyframes
        self.passes += 1
        eviction = Eviction(
            slot_map=slot_map,
            row_map=row_map,
            keyframes_kept=self.map.n_cached_keyframes,
            keyframes_evicted=len(cached) - self.map.n_cached_keyframes,
            points_kept=self.map.n_points,
            points_evicted=n_points - self.map.n_points,
        )
        logger.debug(
            "cache eviction: kept %d keyframes and %d points, evicted %d keyframes and %d points",
            eviction.keyframes_kept, eviction.keyframes_evicted, eviction.points_kept, eviction.points_evicted,
        )  # fmt: skip
        return eviction
