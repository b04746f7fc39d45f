"""What the backend's map does to the frontend's cache: map updates applied (replacement
semantics, see ``zenslam.schemas.map_update``) and the backend's keyframes restored into it.

An update replaces the listed points (creating unknown ones a held keyframe observes), the poses
and keypoint-to-point associations of the held keyframes it corrects, carries the keyframes the
backend has not mapped yet with their parent's correction, then deletes the removed points and
keyframes. ``MapSync`` also keeps the tracker's last frame where it was relative to its reference
keyframe (ORB-SLAM2's UpdateLastFrame), so the motion model predicts in the corrected map.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence

import numpy as np

from zenslam.frontend.keyframe import KeyFrame
from zenslam.frontend.local_map import LocalMap
from zenslam.frontend.tracking_state import TrackerState
from zenslam.geometry import invert_T, transform_points
from zenslam.schemas.map_update import KeyframeCorrection, MapUpdate
from zenslam.schemas.relocalisation import MapPoints

logger = logging.getLogger(__name__)


class MapSync:
    """Applies the backend's map updates to the tracker's cache ``local_map`` and its ``state``."""

    def __init__(self, local_map: LocalMap, state: TrackerState) -> None:
        self.map = local_map
        self.state = state

    def apply(self, update: MapUpdate) -> None:
        """Apply the backend's correction to the cache and move the last frame with its reference keyframe."""
        state = self.state
        reference = self.map.keyframe(state.reference_slot) if state.reference_slot >= 0 else None
        T_last_ref = None
        if state.last is not None and reference is not None:
            T_last_ref = state.last.T_cam_world @ reference.T_world_cam
        apply_map_update(self.map, update)
        reference = self.map.keyframe(state.reference_slot) if state.reference_slot >= 0 else None
        if T_last_ref is not None and reference is not None:
            before = invert_T(state.last.T_cam_world)[:3, 3]
            state.last.T_cam_world = T_last_ref @ reference.T_cam_world
            logger.debug(
                "map update of keyframe %d (%s) applied after frame %d: last frame moved %.3f m (reference keyframe %d)",
                update.keyframe_id, update.kind, state.last.frame.index,
                float(np.linalg.norm(invert_T(state.last.T_cam_world)[:3, 3] - before)), reference.id,
            )  # fmt: skip


def apply_map_update(local_map: LocalMap, update: MapUpdate) -> None:
    """Apply the backend's correction to the cache: replace listed points (creating unknown ones),
    keyframe poses and keypoint-to-point associations, then delete removed points and keyframes.

    Replacement semantics make a second application harmless. Keyframes the cache does not hold
    (never had, or evicted) are skipped: it cannot rebuild their keypoints. Unknown points are
    created only when a held keyframe listed in the update observes them: the cache holds its
    keyframes' points (tracking reaches points through keyframes), so an evicted point comes back
    when a held keyframe is associated with it again, and a correction listing the whole map does
    not copy it into the cache.
    """
    corrections = _fitting(local_map, update.keyframes)
    moved = _poses_of(local_map, corrections)
    held = [c.map_point_ids for c in corrections if local_map.slot_of(c.id) >= 0]
    local_map.replace_points(update, np.concatenate(held) if held else np.zeros(0, dtype=np.int64))
    _replace_keyframes(local_map, corrections)
    _carry_unmapped_keyframes(local_map, update, moved)
    local_map.remove_points(update.removed_point_ids)
    for keyframe_id in np.asarray(update.removed_keyframe_ids, dtype=np.int64).tolist():
        local_map.remove_keyframe(keyframe_id)


def restore_keyframes(local_map: LocalMap, keyframes: Sequence[KeyFrame], points: MapPoints) -> list[int]:
    """Bring keyframes of the backend's map into the cache (evicted ones, or never held) with the
    points they observe, as the backend describes them (``points``); returns their new slots.

    Keyframes the cache holds stay as they are. Listed points the cache holds take the backend's
    values; unknown ones observed by a restored keyframe are created (as a map update creates
    them). A restored keyframe is no new keyframe: it does not advance ``n_keyframes``, and it adds
    to ``n_observations`` only of the points it brings (the others already count it, see
    ``LocalMap.retain``).
    """
    restored = [kf for kf in sorted(keyframes, key=lambda k: k.id) if local_map.slot_of(kf.id) < 0]
    observed = [np.asarray(kf.map_point_ids, dtype=np.int64) for kf in restored]
    known = local_map.rows_of_ids(points.ids) >= 0
    listed = MapUpdate(
        keyframe_id=-1, stamp_ns=0, point_ids=np.asarray(points.ids, dtype=np.int64), p_world=points.p_world,
        descriptors=points.descriptors, normals=points.normals, min_distance_m=points.min_distance_m,
        max_distance_m=points.max_distance_m,
    )  # fmt: skip
    local_map.replace_points(listed, np.concatenate(observed) if observed else np.zeros(0, dtype=np.int64))
    brought = np.zeros(local_map.n_points, dtype=bool)
    rows = local_map.rows_of_ids(points.ids)
    brought[rows[(rows >= 0) & ~known]] = True
    return [local_map.add_held_keyframe(keyframe, brought) for keyframe in restored]


def _fitting(local_map: LocalMap, corrections: Sequence[KeyframeCorrection]) -> list[KeyframeCorrection]:
    """``corrections`` less those of held keyframes whose associations do not list one point per
    keypoint: a damaged message, which names a keyframe it cannot describe (skipped, with a
    warning; the keyframe keeps what it had)."""
    fitting = []
    for correction in corrections:
        slot = local_map.slot_of(correction.id)
        keyframe = local_map.keyframe(slot) if slot >= 0 else None
        if keyframe is not None and len(correction.map_point_ids) != len(keyframe.map_point_ids):
            logger.warning(
                "map update: keyframe %d's correction lists %d point associations for its %d keypoints; skipped",
                correction.id, len(correction.map_point_ids), len(keyframe.map_point_ids),
            )  # fmt: skip
            continue
        fitting.append(correction)
    return fitting


def _poses_of(local_map: LocalMap, corrections: list[KeyframeCorrection]) -> dict[int, np.ndarray]:
    """Slot -> current T_world_cam of the known keyframes among ``corrections``."""
    slots = (local_map.slot_of(c.id) for c in corrections)
    return {s: local_map.keyframe(s).T_world_cam for s in slots if s >= 0 and local_map.keyframe(s) is not None}


def _replace_keyframes(local_map: LocalMap, corrections: list[KeyframeCorrection]) -> None:
    """Replace the poses and associations of the known keyframes among ``corrections``."""
    replaced = []
    for correction in corrections:
        slot = local_map.slot_of(correction.id)
        if slot >= 0 and local_map.keyframe(slot) is not None:
            local_map.replace_keyframe(
                slot,
                dataclasses.replace(
                    local_map.keyframe(slot),
                    T_world_cam=np.asarray(correction.T_world_cam, dtype=float),
                    map_point_ids=np.asarray(correction.map_point_ids, dtype=np.int64),
                ),
            )
            replaced.append(slot)
    local_map.reobserve(replaced)


def _carry_unmapped_keyframes(local_map: LocalMap, update: MapUpdate, before: dict[int, np.ndarray]) -> None:
    """Move the keyframes made after ``update.keyframe_id`` (the backend has not mapped them yet)
    and the points they created with their spanning-tree parent's correction, as ORB-SLAM corrects
    the last frame through its reference keyframe: without it, tracking between an update and the
    next would mix the corrected map with keyframes placed on the old one."""
    correction = {s: local_map.keyframe(s).T_world_cam @ invert_T(T) for s, T in before.items()}
    for slot in range(local_map.n_slots):
        keyframe = local_map.keyframe(slot)
        if keyframe is None or keyframe.id <= update.keyframe_id or slot in before or local_map.parent(slot) not in correction:
            continue
        C = correction[slot] = correction[local_map.parent(slot)]
        local_map.replace_keyframe(slot, dataclasses.replace(keyframe, T_world_cam=C @ keyframe.T_world_cam))
        rows = local_map.rows_of_ids(keyframe.new_point_ids[~np.isin(keyframe.new_point_ids, update.point_ids)])
        rows = rows[rows >= 0]
        local_map.set_row_positions(rows, transform_points(C, local_map.p_world[rows]))
